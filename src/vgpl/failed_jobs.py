"""A Hydra callback that names every failed job of a multirun sweep.

Hydra runs every job of a sweep, keeps each failure in its job's return, and then raises only the
first; the other failures would stay unreported. :class:`FailedJobs` logs one error line per failed
job, with its number, overrides and error, as the job ends (in the job's process, so it reaches the
job's log file and the console whatever the launcher).
"""

from __future__ import annotations

import logging
from typing import Any

from hydra.core.utils import JobReturn, JobStatus
from hydra.experimental.callback import Callback
from hydra.types import RunMode
from omegaconf import DictConfig

log = logging.getLogger("vgpl")


class FailedJobs(Callback):
    """Logs ``job <num> (<overrides>) failed: <error>`` for each failed job of a multirun."""

    def on_job_end(self, config: DictConfig, job_return: JobReturn, **kwargs: Any) -> None:
        hydra_cfg = job_return.hydra_cfg.hydra if job_return.hydra_cfg is not None else None
        if job_return.status != JobStatus.FAILED or hydra_cfg is None or hydra_cfg.mode != RunMode.MULTIRUN:
            return  # a single run's own traceback says it already
        error = job_return._return_value
        log.error("job %s (%s) failed: %s: %s", hydra_cfg.job.num, " ".join(job_return.overrides or []), type(error).__name__, error)
