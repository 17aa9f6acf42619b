"""Several trainings at once, each in its own process (the pipeline's ``task.modules_at_once``).

On a CPU a small model's step does not use two threads well, so two modules trained side by side
on one thread each finish more steps in the same minutes than the two trained one after the other
(``benchmarks/modules_at_once.py``, docs/benchmarks.md). Each process is spawned, not forked, so no torch thread pool is shared.
"""

from __future__ import annotations

from collections.abc import Callable

from omegaconf import DictConfig

from vgpl.allocator import keep_freed_memory
from vgpl.workers import worker_pool


def threads_each(threads: int, jobs: int) -> int:
    """Torch threads for each of ``jobs`` processes sharing ``threads`` (at least 1)."""
    return max(1, threads // jobs)


def run_at_once(fn: Callable[[DictConfig], dict], configs: dict[str, DictConfig]) -> dict[str, dict]:
    """``fn(config)`` for every named config, all at once in spawned processes; returns name -> result.

    ``fn`` must be importable (a module-level function) and each config resolved (no ``${hydra:...}``):
    a child process has no Hydra run. Each child keeps freed memory as run_task does where every config
    asks for it (``keep_freed_memory``), and ends with this process (``vgpl.workers``). The first failure
    is raised here, after the others end."""
    keep = all(c.get("keep_freed_memory", False) for c in configs.values())
    with worker_pool(len(configs), keep_freed_memory if keep else None) as pool:
        jobs = {name: pool.submit(fn, c) for name, c in configs.items()}
        return {name: job.result() for name, job in jobs.items()}
