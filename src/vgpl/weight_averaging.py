"""An exponential moving average (EMA) of a module's weights during training, on Lightning's
``WeightAveraging`` callback: validation and the saved ``state_dict`` use the average, the weights
being trained are kept under the checkpoint's ``current_model_state`` (so ``ckpt_path=last``
resumes both, and ``trained_weights_checkpoint`` recovers them for comparison).

Why: with batch 2 the inference module's global parameter head drifts between checkpoints; an
average over the last ~1 / (1 - decay) steps settles it (docs/design.md).
"""

from __future__ import annotations

from pathlib import Path

import torch
from lightning.pytorch.callbacks import WeightAveraging


def ema_decay_at(decay: float, n_averaged: int) -> float:
    """The decay used at the update after ``n_averaged`` ones: ``min(decay, n / (n + 1))``. Until
    the average spans ``1 / (1 - decay)`` steps it is the plain mean of every step so far (an
    EMA from the first step would keep ``decay ** n`` of the random initial weights; TensorFlow's
    ``(1 + n) / (10 + n)`` warm-up would average over only the last ~n / 9 steps), then an EMA
    over that many steps."""
    return min(decay, n_averaged / (n_averaged + 1.0))


class ExponentialMovingAverage(WeightAveraging):
    """EMA of every parameter and buffer, updated after each optimiser step from ``start_step`` on."""

    def __init__(self, decay: float, start_step: int = 0) -> None:
        if not 0.0 < decay < 1.0:
            raise ValueError(f"ema decay={decay}: expected a number in (0, 1), e.g. 0.998 (an average over ~500 steps)")
        if start_step < 0:
            raise ValueError(f"ema start_step={start_step}: expected >= 0")

        def average(averaged: torch.Tensor, current: torch.Tensor, n_averaged: torch.Tensor) -> torch.Tensor:
            d = ema_decay_at(decay, int(n_averaged))
            return d * averaged + (1.0 - d) * current

        super().__init__(avg_fn=average, use_buffers=True)
        self.decay, self.start_step = decay, start_step
        self._trained_state: dict | None = None

    def should_update(self, step_idx: int | None = None, epoch_idx: int | None = None) -> bool:
        return step_idx is not None and step_idx >= self.start_step

    def on_train_end(self, trainer, pl_module) -> None:
        # The parent copies the average into the module; keep the trained weights for a save after fit
        # (vgpl.tasks.stage.fit writes last.ckpt then), or its current_model_state would be the average.
        self._trained_state = {k: v.detach().clone() for k, v in pl_module.state_dict().items()}
        super().on_train_end(trainer, pl_module)

    def on_save_checkpoint(self, trainer, pl_module, checkpoint: dict) -> None:
        super().on_save_checkpoint(trainer, pl_module, checkpoint)
        if self._trained_state is not None and "current_model_state" in checkpoint:
            checkpoint["current_model_state"] = self._trained_state


def trained_weights_checkpoint(src: str | Path, dst: str | Path) -> Path:
    """Write a copy of checkpoint ``src`` whose ``state_dict`` holds the weights being trained, not
    their EMA (``dst`` beside ``src``: loading needs the config.yaml of that folder)."""
    src, dst = Path(src), Path(dst)
    ckpt = torch.load(src, map_location="cpu", weights_only=False)
    if "current_model_state" not in ckpt:
        raise KeyError(f"{src}: no 'current_model_state' (trained without model.<stage>.ema.decay), its state_dict is already the trained weights")
    ckpt["state_dict"] = ckpt.pop("current_model_state")
    ckpt.pop("averaging_state", None)
    torch.save(ckpt, dst)
    return dst
