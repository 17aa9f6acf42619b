"""The main job (`python run.py`, the quick pipeline) from nothing: wall time, each step's
seconds and each training's steps run of those asked, with the machine described.

    python benchmarks/main_job.py                 # one JSON line on stdout (about 9 minutes)
    python benchmarks/main_job.py --keep /tmp/mj  # keep its data, checkpoints and run folder
    python benchmarks/main_job.py -- env=mass_rope seed=1 >> results/quick.jsonl   # a row of README's tables

It runs `run.py` in a fresh root folder (data, checkpoints and outputs under it), so nothing
generated or trained before is reused, then reads the run's ``pipeline.json`` and its parameter
numbers (``accuracy``). Extra arguments after ``--`` go to run.py as Hydra overrides.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import describe  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


ACCURACY_KEYS = ("n_test", "param_mae_pct", "param_mae_pct_std", "param_bias_pct", "midpoint_param_mae_pct",
                 "future_mse_x1e4@1", "future_mse_x1e4@5", "future_mse_x1e4@10", "future_mse_x1e4@20",
                 "refine_mse_x1e4_before", "refine_mse_x1e4_after", "flow_statistics_param_mae_pct")


def accuracy(run_dir: Path) -> dict:
    """The run's numbers: each evaluated ablation's parameter MAE, its std and bias, the range midpoint's
    MAE on the same videos, the future MSE and the refinement (``evaluate/<ablation>/metrics.json``); the prior's oracle
    (``identifiability/identifiability.json``)."""
    out = {"evaluate": {}}
    for metrics in sorted(run_dir.glob("evaluate/*/metrics.json")):
        m = json.loads(metrics.read_text())
        out["evaluate"][metrics.parent.name] = {k: round(m[k], 3) if isinstance(m[k], float) else m[k] for k in ACCURACY_KEYS if k in m}
    ident = run_dir / "identifiability" / "identifiability.json"
    if ident.exists():
        out |= {k: round(v, 3) for k, v in json.loads(ident.read_text()).items() if k.startswith("oracle_param_mae_pct/")}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--keep", help="root folder to run in and keep (default: a temporary one, removed after)")
    parser.add_argument("overrides", nargs="*", help="Hydra overrides for run.py (after --)")
    args = parser.parse_args()
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="vgpl_main_job_"))
    if args.keep and root.exists() and any(root.iterdir()):
        parser.error(f"--keep {root}: not empty; the main job is measured from nothing")
    run_dir = root / "run"
    command = [sys.executable, str(REPO / "run.py"), f"paths.root_dir={root}", f"hydra.run.dir={run_dir}", *args.overrides]
    start = time.perf_counter()
    proc = subprocess.run(command, cwd=REPO, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if proc.returncode != 0:
        sys.exit(f"main job failed ({' '.join(command)}):\n{proc.stderr[-3000:]}")
    summary = json.loads((run_dir / "pipeline.json").read_text())
    preset = next((o.split("=", 1)[1] for o in args.overrides if o.startswith("experiment=")), "quick")
    print(json.dumps({"benchmark": "main_job", "preset": preset, "wall_s": round(wall, 1), "overrides": args.overrides, **summary,
                      **accuracy(run_dir), "machine": describe()}))
    if not args.keep:
        shutil.rmtree(root)


if __name__ == "__main__":
    main()
