"""Two task=evaluate runs of one env on the same test videos (e.g. two inference modules trained
on the same prior and proposals): each one's parameter MAE (% of range) and T+20 MSE x 1e4 (or T+k: --step), and
B - A paired by rollout id with a bootstrap interval (vgpl.eval.paired). task=report pools runs of
one method; this compares two (session 37: the inference anneal against the constant rate).

Usage: python scripts/experiments/paired_evaluations.py --env rigid_fall [--step 20] A_DIR B_DIR [C_DIR ...]
       (each DIR holds a params.csv; the first is the reference A; --step k pairs T+k, which
       params.csv carries at Table 2's horizons since session 71, at the last one before)
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from vgpl.eval.metrics import param_error_pct
from vgpl.eval.paired import paired_bootstrap
from vgpl.eval.rollout import FUTURE  # the per-video columns task=evaluate writes to params.csv
from vgpl.eval.tables import read_params_csv
from vgpl.sim.envs import ENVS, make_scene


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dirs", nargs="+", type=Path, help="task=evaluate folders; the first is the reference")
    parser.add_argument("--env", required=True, choices=sorted(ENVS))
    parser.add_argument("--step", type=int, default=20, help="the T+k to pair the future error at (default 20)")
    args = parser.parse_args()
    if len(args.dirs) < 2:
        raise SystemExit("give at least two task=evaluate folders to compare")
    scene = make_scene(args.env)  # its parameter names and ranges, as pooled_minimum.py reads them
    low, high = torch.as_tensor(scene.param_low), torch.as_tensor(scene.param_high)
    names = list(scene.param_names)
    column, k = FUTURE.format(args.step), args.step
    try:
        runs = [read_params_csv(d / "params.csv", names, (column,)) for d in args.dirs]
    except ValueError as e:
        raise SystemExit(str(e)) from None
    ids = sorted(set.intersection(*(set(r.rollout_ids) for r in runs)))
    if not ids:
        raise SystemExit(f"{[str(d) for d in args.dirs]}: no test video in common")
    errors, future = [], []
    for run in (r.select(ids) for r in runs):
        errors.append(param_error_pct(run.inferred, run.truth, low, high).mean(1))  # [R]
        future.append(run.columns[column])
    print(f"{args.env}, {len(ids)} test videos in common; B - A paired by video, 95% bootstrap interval")
    print(f"A {args.dirs[0]}: parameter MAE {errors[0].mean():.2f}% (std {errors[0].std():.2f}), T+{k} {future[0].mean():.1f} (median {future[0].median():.1f})")
    for d, e, f in zip(args.dirs[1:], errors[1:], future[1:]):
        pe, pf = paired_bootstrap(errors[0], e), paired_bootstrap(future[0], f)
        print(f"B {d}: parameter MAE {e.mean():.2f}% (std {e.std():.2f}), T+{k} {f.mean():.1f} (median {f.median():.1f})")
        print(f"  B - A: parameter MAE {pe['mean_diff']:+.2f} [{pe['low']:+.2f}, {pe['high']:+.2f}] pts, A lower on {pe['reference_lower_share']:.0%};"
              f" T+{k} {pf['mean_diff']:+.1f} [{pf['low']:+.1f}, {pf['high']:+.1f}], A lower on {pf['reference_lower_share']:.0%}"
              f" (sign test p {pf['sign_p']:.2g})")


if __name__ == "__main__":
    main()
