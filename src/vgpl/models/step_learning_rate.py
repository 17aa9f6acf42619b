"""Learning rates set from the global step at each batch start, not by a Lightning scheduler.

A fit cut by trainer.max_time, or resumed from a checkpoint that had no scheduler, keeps its
global step but not a scheduler's own counter; a rate computed from the global step is the same
in an interrupted fit as in an uninterrupted one (DynamicsPrior's per-epoch decay, the final
anneal of VisualPrior, ``AnnealedLearningRate``). The anneal also reads the
training clock (Lightning's Timer, which a resume restores), so a fit stopped by
trainer.max_time ends annealed too."""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence

import lightning as L
from lightning.pytorch.callbacks import Timer

log = logging.getLogger(__name__)


def set_learning_rate(module: L.LightningModule, lr: float | Sequence[float]) -> None:
    """Set the module's optimiser to ``lr``: one rate for every parameter group, or one rate per
    group in order. The first group's rate is logged as train/lr."""
    groups = module.trainer.optimizers[0].param_groups
    rates = [lr] * len(groups) if isinstance(lr, (int, float)) else list(lr)
    if len(rates) != len(groups):
        raise ValueError(f"set_learning_rate: {len(rates)} rates for {len(groups)} parameter groups")
    for group, rate in zip(groups, rates):
        group["lr"] = rate
    module.log("train/lr", rates[0], batch_size=1)


def annealed_fraction(step: int, max_steps: int, anneal_steps: int, elapsed_s: float | None = None,
                      budget_s: float | None = None, stage: str = "visual", option: str = "lr_anneal_steps") -> float:
    """1 before step ``max_steps - anneal_steps``, then 0.5 (1 + cos(pi x progress)), reaching 0
    at ``max_steps`` (the step after the last one taken).

    With a time budget (trainer.max_time, ``budget_s`` seconds, ``elapsed_s`` of them spent) the
    anneal also spans the same share ``anneal_steps / max_steps`` of the budget's end, and the rate
    follows whichever of the two schedules is further on: a fit the clock stops before max_steps
    still ends at zero, and one that reaches max_steps first anneals by step as before. ``stage``
    (visual) and ``option`` (the net's key that asked for the schedule) name the config
    key in the error for a fit without max_steps."""
    if max_steps <= 0:
        raise ValueError(f"model.{stage}.net.{option}={anneal_steps} needs a finite model.{stage}.trainer.max_steps, "
                         f"or trainer.max_steps, which every stage inherits (got {max_steps})")
    progress = (step - (max_steps - anneal_steps)) / anneal_steps
    if budget_s is not None and elapsed_s is not None and budget_s > 0:
        share = min(anneal_steps / max_steps, 1.0)
        progress = max(progress, (elapsed_s - (1.0 - share) * budget_s) / (share * budget_s))
    return 1.0 if progress <= 0 else 0.5 * (1.0 + math.cos(math.pi * min(progress, 1.0)))


def training_clock(trainer: L.Trainer) -> tuple[float | None, float | None]:
    """(seconds of training spent, trainer.max_time in seconds), or (None, None) without a
    max_time. Lightning's Timer keeps the time spent across a resume; under DDP rank 0's clock is
    broadcast, so every rank sets the same rate."""
    timer = next((c for c in trainer.callbacks if isinstance(c, Timer)), None)
    if timer is None or timer.time_remaining() is None:
        return None, None
    elapsed = timer.time_elapsed()
    return trainer.strategy.broadcast(elapsed), elapsed + timer.time_remaining()


def unfinished_anneal(stage: str, anneal_steps: int, steps: int, max_steps: int, elapsed_s: float | None = None,
                      budget_s: float | None = None) -> str | None:
    """The warning for a fit that stopped before its anneal reached zero (on max_epochs, or any stop
    other than max_steps and max_time, both of which end it at zero), so that its last.ckpt holds
    weights from a rate above zero; None when the anneal is off or done."""
    if anneal_steps <= 0:
        return None
    reached = annealed_fraction(steps, max_steps, anneal_steps, elapsed_s, budget_s, stage)
    if reached <= 0.0:
        return None
    where = "before its learning-rate anneal began" if reached >= 1.0 else f"mid-anneal, at {reached:.0%} of lr"
    return (f"{stage}: stopped at step {steps} of {max_steps}, {where} (model.{stage}.net.lr_anneal_steps={anneal_steps}); "
            f"resume with ckpt_path=last model.{stage}.trainer.max_time=null to finish it")


class AnnealedLearningRate:
    """LightningModule mixin: with hparams ``lr_anneal_steps`` = K > 0 the learning rate is
    constant until the last K steps of trainer.max_steps, then falls to zero along a half cosine,
    and under a trainer.max_time the same share K / max_steps of the time budget anneals too,
    whichever is further on (``annealed_fraction``). The rate is a function of global_step and of
    the Timer's time spent, both restored by a resume, so a cut fit resumes on its schedule.

    A module names its config group in ``anneal_stage`` and may override ``base_learning_rates``
    (one rate per optimiser parameter group, as configure_optimizers builds them)."""

    anneal_stage: str  # model.<anneal_stage>.net.lr_anneal_steps: named in errors and warnings

    def base_learning_rates(self) -> list[float]:
        return [self.hparams.lr]

    def on_train_batch_start(self, batch, batch_idx) -> None:
        if self.hparams.lr_anneal_steps <= 0:
            return
        fraction = annealed_fraction(self.global_step, self.trainer.max_steps, self.hparams.lr_anneal_steps,
                                     *training_clock(self.trainer), stage=self.anneal_stage)
        set_learning_rate(self, [rate * fraction for rate in self.base_learning_rates()])

    def on_train_end(self) -> None:
        """Warn when the fit stopped (max_epochs) before its anneal reached zero: its last.ckpt
        then holds weights from a rate above zero."""
        unfinished = unfinished_anneal(self.anneal_stage, self.hparams.lr_anneal_steps, self.global_step,
                                       self.trainer.max_steps, *training_clock(self.trainer))
        if unfinished:
            log.warning(unfinished)
