"""Learning rates set from the global step at each batch start, not by a Lightning scheduler.

A fit cut by trainer.max_time, or resumed from a checkpoint that had no scheduler, keeps its
global step but not a scheduler's own counter; a rate computed from the global step is the same
in an interrupted fit as in an uninterrupted one (DynamicsPrior's per-epoch decay, VisualPrior's
final anneal)."""

from __future__ import annotations

import math

import lightning as L


def set_learning_rate(module: L.LightningModule, lr: float) -> None:
    """Set every parameter group of the module's optimiser to ``lr`` and log it as train/lr."""
    for group in module.trainer.optimizers[0].param_groups:
        group["lr"] = lr
    module.log("train/lr", lr, batch_size=1)


def annealed_fraction(step: int, max_steps: int, anneal_steps: int) -> float:
    """1 before step ``max_steps - anneal_steps``, then 0.5 (1 + cos(pi x progress)), reaching 0
    at ``max_steps`` (the step after the last one taken)."""
    if max_steps <= 0:
        raise ValueError(f"model.visual.net.lr_anneal_steps={anneal_steps} needs a finite trainer max_steps (got {max_steps})")
    progress = (step - (max_steps - anneal_steps)) / anneal_steps
    return 1.0 if progress <= 0 else 0.5 * (1.0 + math.cos(math.pi * min(progress, 1.0)))


def unfinished_anneal(stage: str, anneal_steps: int, steps: int, max_steps: int) -> str | None:
    """The warning for a fit that stopped (on trainer.max_time) before its anneal reached zero, so
    that its last.ckpt holds weights from a rate above zero; None when the anneal is off or done."""
    if anneal_steps <= 0 or steps >= max_steps:
        return None
    where = ("before its learning-rate anneal began" if steps <= max_steps - anneal_steps else
             f"mid-anneal, at {annealed_fraction(steps, max_steps, anneal_steps):.0%} of lr")
    return (f"{stage}: stopped at step {steps} of {max_steps}, {where} (model.{stage}.net.lr_anneal_steps={anneal_steps}); "
            f"resume with ckpt_path=last model.{stage}.trainer.max_time=null to finish it")
