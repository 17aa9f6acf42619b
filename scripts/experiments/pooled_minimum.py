"""Where does an inference module's parameter bias come from? (session 26, a diagnostic)

Trained only through the prior's rollout loss, a P head that reads part of the scene-to-scene
variation shrinks towards the single value that is best on average: the minimum of the prior's
mean rollout L1 over the test scenes (the oracle sweep of ``task=evaluate_dynamics``, truth for
everything else). Its mean then sits at that pooled minimum, not at the truth's mean. This prints
the pooled minimum (grid argmin, and a parabola through it and its neighbours) beside the true and
inferred means of each evaluation's params.csv, in the parameter's units and as % of the range.

Usage: python scripts/experiments/pooled_minimum.py ENV PARAM ORACLE_METRICS_JSON PARAMS_CSV [PARAMS_CSV ...]
"""

from __future__ import annotations

import json
import sys

import numpy as np

from vgpl.eval.tables import read_params_csv
from vgpl.sim.envs import make_scene


def pooled_minimum(curve: list[float], low: float, high: float) -> tuple[float, float]:
    """Grid argmin of a loss sampled on linspace(low, high, len(curve)), and the vertex of the
    parabola through it and its two neighbours (the grid argmin itself at an end of the range)."""
    x = np.linspace(low, high, len(curve))
    i = int(np.argmin(curve))
    if i in (0, len(curve) - 1):
        return float(x[i]), float(x[i])
    y0, y1, y2 = curve[i - 1], curve[i], curve[i + 1]
    step = x[1] - x[0]
    return float(x[i]), float(x[i] + 0.5 * step * (y0 - y2) / (y0 - 2 * y1 + y2))


def main(env: str, param: str, oracle: str, evaluations: list[str]) -> None:
    scene = make_scene(env)
    j = scene.param_names.index(param)
    low, high = float(scene.param_low[j]), float(scene.param_high[j])
    pct = lambda v: 100 * v / (high - low)  # noqa: E731
    with open(oracle) as f:
        grid, vertex = pooled_minimum(json.load(f)[f"rollout_l1_over_grid/{param}"], low, high)
    print(f"{env} {param}: pooled minimum of the prior's rollout L1 {grid:.4g} on the grid, {vertex:.4g} by parabola ({oracle})")
    for path in evaluations:
        table = read_params_csv(path, [param])
        true, inferred = table.truth[:, 0].numpy(), table.inferred[:, 0].numpy()
        print(f"  {path}: true mean {true.mean():.4g}, inferred mean {inferred.mean():.4g} (bias {pct(inferred.mean() - true.mean()):+.1f}% of the range; "
              f"pooled minimum - true mean {pct(vertex - true.mean()):+.1f}%), inferred std {inferred.std():.4g} against {true.std():.4g}")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4:])
