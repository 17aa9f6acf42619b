"""Task functions called by run.py: each takes the composed config and returns a summary dict.

Tasks are imported on first use, so starting one task never imports another's dependencies.
"""

from __future__ import annotations

import importlib

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import InterpolationResolutionError

from vgpl.allocator import keep_freed_memory

TASKS: dict[str, str] = {
    "generate": "vgpl.tasks.generate:generate",
    "demo": "vgpl.tasks.demo:demo",
    "train_dynamics": "vgpl.tasks.train_dynamics:train_dynamics",
    "evaluate_dynamics": "vgpl.tasks.train_dynamics:evaluate_dynamics",
    "train_visual": "vgpl.tasks.train_visual:train_visual",
    "export_proposals": "vgpl.tasks.train_visual:export_proposals",
    "train_inference": "vgpl.tasks.train_inference:train_inference",
    "train_baseline": "vgpl.tasks.baseline:train_baseline",
    "evaluate": "vgpl.tasks.evaluate:evaluate",
    "ground": "vgpl.tasks.ground:ground",
    "report": "vgpl.tasks.evaluate:report",
    "compare": "vgpl.tasks.compare:compare",
    "free_fall_gravity": "vgpl.tasks.free_fall:free_fall_gravity",
    "pipeline": "vgpl.tasks.pipeline:pipeline",
    "results": "vgpl.tasks.results:results",
}


def check_resolvable(cfg: DictConfig) -> None:
    """Resolve every interpolation of the composed config once, without changing it, so that a key
    which cannot resolve (say ``experiment=standard_steps`` on an env with no reference steps) fails
    before the task reads data or writes anything: a stage's trainer is otherwise resolved only when
    it is built, after its data are loaded. Values left ``???`` are not checked here; the task that
    needs one says so."""
    try:
        OmegaConf.to_container(cfg, resolve=True)
    except InterpolationResolutionError as e:
        reason = str(e.msg).splitlines()[0]
        raise ValueError(f"task={cfg.task.name}: the config key '{e.full_key}' cannot be resolved: {reason} "
                         "(checked before the task started; nothing was read or written)") from e


def run_task(cfg: DictConfig) -> dict:
    name = cfg.task.name
    if name not in TASKS:
        raise ValueError(f"unknown task.name '{name}': expected one of {sorted(TASKS)}")
    check_resolvable(cfg)
    if cfg.get("keep_freed_memory", False):
        keep_freed_memory()
    module, function = TASKS[name].split(":")
    return getattr(importlib.import_module(module), function)(cfg)
