"""One logged scalar against the training step, read from runs' TensorBoard event files (all of a
run's files together, so a run resumed in several stops reads as one curve): a Markdown table,
step by run. Session 39: the inference module's validation gravity MAE from 3,000 to 6,000 steps.

Usage: python scripts/experiments/val_curve.py [--tag val/param_mae_pct] LABEL=TB_DIR [LABEL=TB_DIR ...]
       (TB_DIR: a checkpoint folder's tensorboard/, e.g. checkpoints/<run>/rigid_fall/inference/tensorboard)
"""

from __future__ import annotations

import argparse
from pathlib import Path

from tensorboard.backend.event_processing.event_accumulator import EventAccumulator


def scalar_curve(folder: Path, tag: str) -> dict[int, float]:
    """step -> value of ``tag`` over every event file under ``folder``; a later file's value wins
    at a step logged twice (a resumed run repeats the step it resumed from)."""
    files = sorted(folder.rglob("events.out.tfevents.*"), key=lambda p: p.stat().st_mtime)
    if not files:
        raise SystemExit(f"{folder}: no TensorBoard event files (expected a run's tensorboard/ folder)")
    curve: dict[int, float] = {}
    for path in files:
        events = EventAccumulator(str(path), size_guidance={"scalars": 0})
        events.Reload()
        if tag in events.Tags()["scalars"]:
            curve.update({e.step: e.value for e in events.Scalars(tag)})
    if not curve:
        raise SystemExit(f"{folder}: no scalar '{tag}' in {len(files)} event files")
    return curve


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", help="LABEL=TB_DIR")
    parser.add_argument("--tag", default="val/param_mae_pct", help="the scalar (default: val/param_mae_pct)")
    args = parser.parse_args()
    labels, curves = [], []
    for run in args.runs:
        label, sep, folder = run.partition("=")
        if not sep:
            raise SystemExit(f"'{run}': expected LABEL=TB_DIR")
        labels.append(label)
        curves.append(scalar_curve(Path(folder), args.tag))
    print(f"| step | " + " | ".join(labels) + " |")
    print("|---|" + "---|" * len(labels))
    for step in sorted(set().union(*curves)):
        values = [f"{c[step]:.4g}" if step in c else "" for c in curves]
        print(f"| {step} | " + " | ".join(values) + " |")


if __name__ == "__main__":
    main()
