"""One logged scalar against the training step, read from runs' TensorBoard event files (all of a
run's files together, so a run resumed in several stops reads as one curve): a Markdown table,
step by run. Session 39: the inference module's validation gravity MAE from 3,000 to 12,000 steps.

Usage: python scripts/experiments/val_curve.py [--tag val/param_mae_pct] LABEL=TB_DIR [LABEL=TB_DIR ...]
       (TB_DIR: a checkpoint folder's tensorboard/, e.g. checkpoints/<run>/rigid_fall/inference/tensorboard)
"""

from __future__ import annotations

import argparse
from pathlib import Path

from tensorboard.backend.event_processing.event_accumulator import EventAccumulator


def scalar_curve(folder: Path, tag: str) -> dict[int, float]:
    """step -> value of ``tag`` in ``folder``'s event files. TensorBoard's own reader of a folder
    reads its files in name order (the name holds the file's creation time, which a copied run
    keeps and its mtime does not) and drops the steps a resumed run logs again."""
    files = list(folder.glob("events.out.tfevents.*"))
    if not files:
        raise SystemExit(f"{folder}: no TensorBoard event files (expected a run's tensorboard/ folder)")
    events = EventAccumulator(str(folder), size_guidance={"scalars": 0})
    events.Reload()
    if tag not in events.Tags()["scalars"]:
        raise SystemExit(f"{folder}: no scalar '{tag}' in {len(files)} event files")
    return {e.step: e.value for e in events.Scalars(tag)}


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
