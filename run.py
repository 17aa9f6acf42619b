"""The one entry point: ``python run.py task=<name> env=<env> key=value ...`` (Hydra)."""

from __future__ import annotations

import json
import logging

import hydra
from omegaconf import DictConfig

import vgpl  # noqa: F401  (registers the config resolvers, e.g. ${fast_precision:bf16-mixed})

log = logging.getLogger("vgpl")


@hydra.main(version_base="1.3", config_path="conf", config_name="config")
def main(cfg: DictConfig) -> None:
    from vgpl.tasks import run_task
    from vgpl.tasks.summary import closing_tables, terminal_summary

    result = run_task(cfg)
    log.info("result (lists of more than 8 values and per-video maps counted; the files keep them): %s", json.dumps(terminal_summary(result), default=str, indent=1))
    if isinstance(result, dict) and result.get("report"):  # the tables and where the rest is, as the last screen
        print(closing_tables(result["report"]), flush=True)


if __name__ == "__main__":
    main()
