"""task=results: re-render the results tables of the docs from the JSON lines under ``task.dir``
(vgpl.results), or with ``task.check=true`` change nothing and fail naming every table that differs."""

from __future__ import annotations

from pathlib import Path

from hydra.utils import to_absolute_path
from omegaconf import DictConfig

from vgpl.atomic_write import atomic_path
from vgpl.results import read_results, render, stale_blocks


def results(cfg: DictConfig) -> dict:
    rows = read_results(Path(to_absolute_path(str(cfg.task.dir))))
    stale, written = {}, []
    for doc in cfg.task.docs:
        path = Path(to_absolute_path(str(doc)))
        if not path.is_file():
            raise FileNotFoundError(f"task.docs: {path} is not a file")
        text = path.read_text()
        new = render(text, rows, str(path))
        if new == text:
            continue
        stale[str(doc)] = stale_blocks(text, rows)
        if not cfg.task.check:
            with atomic_path(path) as tmp:
                tmp.write_text(new)
            written.append(str(doc))
    if cfg.task.check and stale:
        raise ValueError(f"results tables differ from {cfg.task.dir}/: {stale}; re-render them with python run.py task=results")
    print(f"results tables: {len(rows)} rows of {cfg.task.dir}/; rewritten: {written or 'none'}")
    return {"rows": len(rows), "rewritten": written, "stale": stale}
