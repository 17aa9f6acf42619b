"""Learning rates set from the global step at each batch start, not by a Lightning scheduler.

A fit cut by trainer.max_time, or resumed from a checkpoint that had no scheduler, keeps its
global step but not a scheduler's own counter; a rate computed from the global step is the same
in an interrupted fit as in an uninterrupted one (DynamicsPrior's per-epoch decay, VisualPrior's
final anneal). The anneal also reads the training clock (Lightning's Timer, which a resume
restores), so a fit stopped by trainer.max_time ends annealed too."""

from __future__ import annotations

import math

import lightning as L
from lightning.pytorch.callbacks import Timer


def set_learning_rate(module: L.LightningModule, lr: float) -> None:
    """Set every parameter group of the module's optimiser to ``lr`` and log it as train/lr."""
    for group in module.trainer.optimizers[0].param_groups:
        group["lr"] = lr
    module.log("train/lr", lr, batch_size=1)


def annealed_fraction(step: int, max_steps: int, anneal_steps: int, elapsed_s: float | None = None,
                      budget_s: float | None = None) -> float:
    """1 before step ``max_steps - anneal_steps``, then 0.5 (1 + cos(pi x progress)), reaching 0
    at ``max_steps`` (the step after the last one taken).

    With a time budget (trainer.max_time, ``budget_s`` seconds, ``elapsed_s`` of them spent) the
    anneal also spans the same share ``anneal_steps / max_steps`` of the budget's end, and the rate
    follows whichever of the two schedules is further on: a fit the clock stops before max_steps
    still ends at zero, and one that reaches max_steps first anneals by step as before."""
    if max_steps <= 0:
        raise ValueError(f"model.visual.net.lr_anneal_steps={anneal_steps} needs a finite trainer max_steps (got {max_steps})")
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
    reached = annealed_fraction(steps, max_steps, anneal_steps, elapsed_s, budget_s)
    if reached <= 0.0:
        return None
    where = "before its learning-rate anneal began" if reached >= 1.0 else f"mid-anneal, at {reached:.0%} of lr"
    return (f"{stage}: stopped at step {steps} of {max_steps}, {where} (model.{stage}.net.lr_anneal_steps={anneal_steps}); "
            f"resume with ckpt_path=last model.{stage}.trainer.max_time=null to finish it")
