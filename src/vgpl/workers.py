"""Worker processes that end with the process that started them.

``concurrent.futures`` workers outlive a parent that is killed (SIGTERM, SIGKILL, a closed terminal):
they finish the task in hand and then take the ones already queued, for minutes, on the cores the
next run needs. Each worker here watches its parent and ends within a second of its death. What a
worker had half written is left as the tasks leave it after any kill (``task=generate`` writes
through a temporary file and resumes from the complete shards).
"""

from __future__ import annotations

import multiprocessing
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor


def exit_with_parent(poll_s: float = 1.0) -> threading.Thread:
    """End this process (``os._exit(1)``) within ``poll_s`` seconds of its parent's death, that is once
    it has been handed to another parent. Returns the daemon thread that watches."""
    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(poll_s)
        os._exit(1)

    watcher = threading.Thread(target=watch, name="exit_with_parent", daemon=True)
    watcher.start()
    return watcher


def _start_worker(initializer: Callable[[], object] | None) -> None:
    exit_with_parent()
    if initializer is not None:
        initializer()


def worker_pool(workers: int, initializer: Callable[[], object] | None = None) -> ProcessPoolExecutor:
    """A pool of ``workers`` spawned processes (not forked: no torch thread pool is shared), each
    ending with this process (``exit_with_parent``) and running ``initializer()`` (importable) first."""
    return ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"), initializer=_start_worker,
                               initargs=(initializer,))
