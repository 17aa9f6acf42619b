"""Test callbacks for the learning-rate anneal (vgpl.models.step_learning_rate), shared by the
VisualPrior and InferenceModule tests: the rates each optimiser step used, and a deterministic
stand-in for trainer.max_time's clock."""

from __future__ import annotations

from datetime import timedelta

import lightning as L
from lightning.pytorch.callbacks import Timer
from lightning.pytorch.trainer.states import RunningStage


class LearningRates(L.Callback):
    """The rate of every parameter group at each optimiser step: ``rates[step][group]``;
    ``first_group()`` is the flat list of group 0's (a module with one group)."""

    def __init__(self) -> None:
        self.rates: list[list[float]] = []

    def on_before_optimizer_step(self, trainer, pl_module, optimizer) -> None:
        self.rates.append([g["lr"] for g in optimizer.param_groups])

    def first_group(self) -> list[float]:
        return [step[0] for step in self.rates]


class BatchClock(Timer):
    """trainer.max_time's Timer on a deterministic clock: one second per finished training batch.
    Its time spent is saved in and restored from checkpoints as the real one's is."""

    def __init__(self, budget_s: float) -> None:
        super().__init__(duration=timedelta(seconds=budget_s))
        self.batches = 0

    def on_train_batch_end(self, trainer, *args, **kwargs) -> None:
        self.batches += 1
        super().on_train_batch_end(trainer, *args, **kwargs)

    def time_elapsed(self, stage=RunningStage.TRAINING) -> float:
        return float(self.batches + self._offset) if RunningStage(stage) == RunningStage.TRAINING else 0.0
