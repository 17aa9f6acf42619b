"""Plot the oracle sweep's mean rollout L1 against the swept parameter for several
``task=evaluate_dynamics`` runs (their metrics.json), one line each, with the midpoint's and the
oracle's MAE in the legend.

    python scripts/experiments/plot_oracle_curves.py mass_rope stiffness out.png LABEL=outputs/<run>/metrics.json ...
"""

from __future__ import annotations

import json
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from vgpl.sim.envs import make_scene  # noqa: E402


def main(env: str, param: str, out: str, runs: list[str]) -> None:
    scene = make_scene(env)
    j = scene.param_names.index(param)
    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    for run in runs:
        label, path = run.split("=", 1)
        m = json.load(open(path))
        curve = m[f"rollout_l1_over_grid/{param}"]
        x = np.linspace(scene.param_low[j], scene.param_high[j], len(curve))
        ax.plot(x, np.asarray(curve) / min(curve), marker="o",
                label=f"{label}: oracle {m[f'oracle_param_mae_pct/{param}']:.1f}%")
    ax.set_xlabel(f"{param} given to the prior (truth for everything else)")
    ax.set_ylabel("rollout L1 / its minimum")
    ax.set_title(f"{env}: oracle sweep, midpoint MAE {m[f'midpoint_param_mae_pct/{param}']:.1f}%", fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=120)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4:])
