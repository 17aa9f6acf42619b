"""A training's hold on its stage folder ``<paths.ckpt_dir>/<stage>``: one training at a time, and
never over a trained checkpoint unless the run resumes it or says ``overwrite=true``.

The hold is an exclusive OS lock (``filelock``) on ``<folder>/.train.lock``, taken before anything is
written and kept until the training returns; the OS releases it when the process dies, so a killed
run leaves no stale lock. Under data-parallel training only rank 0 takes it (the other ranks are its
children and write nothing of their own).
"""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from filelock import FileLock, Timeout
from lightning.pytorch.utilities.rank_zero import rank_zero_only

LOCK = ".train.lock"


class StageFolderError(RuntimeError):
    """A stage folder this training may not write now; the message names the folder and the ways out."""


@contextmanager
def hold_stage_folder(folder: Path, resuming: bool, overwrite: bool) -> Iterator[None]:
    """Hold ``folder`` for one training. Refuses (StageFolderError, before anything is written) when
    another training holds it, or when it holds a trained ``last.ckpt`` that this run neither resumes
    (``resuming``: ``ckpt_path`` given) nor replaces (``overwrite``). With ``overwrite`` the previous
    run's TensorBoard events are removed, so the new run's curves are not mixed with them."""
    if getattr(rank_zero_only, "rank", 0) != 0:
        yield
        return
    folder.mkdir(parents=True, exist_ok=True)
    lock = FileLock(folder / LOCK)
    try:
        lock.acquire(timeout=0)
    except Timeout:
        raise StageFolderError(f"{folder}: another training is writing this stage folder (it holds {folder / LOCK}); "
                               "wait for it to end, or train into another paths.ckpt_dir") from None
    try:
        trained = folder / "last.ckpt"
        if trained.is_file() and not resuming:
            if not overwrite:
                raise StageFolderError(f"{folder}: holds a trained checkpoint ({trained.name}) that this run would replace; "
                                       "resume it with ckpt_path=last, or pass overwrite=true to train it again from scratch")
            shutil.rmtree(folder / "tensorboard", ignore_errors=True)
        yield
    finally:
        lock.release()
