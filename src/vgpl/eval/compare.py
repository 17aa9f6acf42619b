"""Two or more evaluations of one test set, paired video by video: is one training recipe's module
really better than another's? Each evaluation's metrics.json keeps every test video's parameter
error (``PER_VIDEO_PARAM``), future error at each horizon (``PER_VIDEO``, tables.py) and
probability of each object type's correct rigidness label (``PER_VIDEO_RIGIDNESS``); this pairs
them by rollout id and bootstraps the mean difference (vgpl.eval.paired), for the parameter MAE,
every T+k and every rigidness both evaluations carry."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

from vgpl.eval.paired import paired_bootstrap, paired_values
from vgpl.eval.tables import PER_VIDEO, paired_steps

PER_VIDEO_PARAM = "per_video_param_mae_pct"  # record key: {rollout id (str): that video's parameter error, % of range, mean over parameters}
PER_VIDEO_RIGIDNESS = "per_video_rigidness_prob@{}/{}"  # record key (T, object type): {rollout id (str): P(correct label), mean over that type's instances}
RIGIDNESS_KEY = re.compile(re.escape(PER_VIDEO_RIGIDNESS.partition("{")[0]) + r"(\d+)/(.+)$")  # its T and object type


def read_record(path: str | Path) -> dict:
    """The metrics.json of a task=evaluate output folder (or the file itself); one ValueError names
    the path and what is missing."""
    path = Path(path)
    file = path / "metrics.json" if path.is_dir() else path
    if not file.is_file():
        raise ValueError(f"{path}: no metrics.json (the output folder of a task=evaluate was expected)")
    record = json.loads(file.read_text())
    if PER_VIDEO_PARAM not in record:
        raise ValueError(f"{file}: no per-video parameter errors ('{PER_VIDEO_PARAM}'): evaluated before they were kept (run task=evaluate "
                         "again, with model=densephysnet for the baseline)")
    return record


def short_names(paths: list[str]) -> list[str]:
    """Each path relative to the folder all of them share ('/a/paper/eval', '/a/joint/eval' ->
    'paper/eval', 'joint/eval'): table labels that differ where the runs do. A path that is that folder keeps its name."""
    resolved = [Path(p).resolve() for p in paths]
    common = Path(os.path.commonpath(resolved)) if len(resolved) > 1 else resolved[0].parent
    return [str(r.relative_to(common)) if r != common else r.name for r in resolved]


def compared_metrics(reference: dict, other: dict) -> list[tuple[str, str]]:
    """(label, record key) of every per-video metric both records carry: the parameter MAE, T+k in
    order, then each object type's rigidness."""
    rigidness = sorted((m for k in reference if (m := RIGIDNESS_KEY.match(k))), key=lambda m: (int(m[1]), m[2]))  # by T, then type
    keys = ([("parameter MAE %", PER_VIDEO_PARAM)] + [(f"T+{k} MSE x 1e4", PER_VIDEO.format(k)) for k in paired_steps([reference, other])]
            + [(f"P(correct rigidness) of {m[2]}, T = {m[1]}", m[0]) for m in rigidness])
    return [(label, key) for label, key in keys if key in reference and key in other]


def paired_comparisons(reference: dict, others: dict[str, dict], reference_name: str = "reference") -> list[dict]:
    """For each of ``others`` (name -> record) and each metric both carry (``compared_metrics``), on
    the videos both evaluated: the two means, the mean difference (other - reference) with its 95%
    bootstrap interval, the share of videos where the reference is lower, the sign test's p
    (``paired_bootstrap``) and the verdict, "higher", "lower" or "not distinguishable" (the other's
    mean against the reference's, by the interval). Records of another env, or with no video in
    common, are refused."""
    found = []
    for name, other in others.items():
        if other.get("env") != reference.get("env"):
            raise ValueError(f"{name}: an evaluation on {other.get('env')!r}, the reference {reference_name} is on {reference.get('env')!r}")
        for label, key in compared_metrics(reference, other):
            ids, a, b = paired_values(reference[key], other[key])
            if not ids:
                raise ValueError(f"{name}: no test video in common with {reference_name} (compare evaluations of one test split)")
            s = paired_bootstrap(a, b)
            verdict = "higher" if s["low"] > 0 else "lower" if s["high"] < 0 else "not distinguishable"
            found.append({"run": name, "metric": label, "key": key, "reference_mean": float(a.mean()), "run_mean": float(b.mean()), **s,
                          "verdict": verdict})
    return found


def compare_rows(comparisons: list[dict], reference_name: str = "reference") -> tuple[list[str], list[list[str]]]:
    """Header and rows of ``paired_comparisons``' results, one per run and metric."""
    rows = [[c["run"], c["metric"], str(c["videos"]), f"{c['reference_mean']:.4g}", f"{c['run_mean']:.4g}",
             f"{c['mean_diff']:+.3g} [{c['low']:+.3g}, {c['high']:+.3g}]", f"{100 * c['reference_lower_share']:.0f}% (p {c['sign_p']:.2g})",
             c["verdict"]] for c in comparisons]
    header = ["run", "metric", "videos", reference_name, "run's", f"run - {reference_name} [95% bootstrap]",
              f"videos where {reference_name} is lower (sign test p)", "the run's is"]
    return header, rows
