"""Several runs of one variant (seeds, or repeated trainings) in one report. Table 1 and Table 2
have one row per (method, ablation, env); given two evaluations of the same variant, a report
would otherwise keep one and drop the other without a word. ``pool_runs`` merges them instead:
every metric is the mean over the runs, each run's parameter MAE and future errors are kept
beside it, and a video's error is its mean over the runs, so the paired comparison averages the
training noise of each video before it bootstraps over videos."""

from __future__ import annotations

import numbers


def variant(record: dict) -> tuple[str, str, str]:
    """(method, ablation, env): what one row of a table and one pooled record stand for. DensePhysNet's
    "ablation" is the flow it learned: ``full`` on flow estimated from the frames, ``simulator_flow``
    on the simulator's privileged flow (records without the key were trained on it). A VGPL
    evaluation with a test-time fit is its ablation's ``+test_time_fit`` variant."""
    method = record.get("method", "vgpl")
    if method == "densephysnet":
        return method, "full" if record.get("flow", "simulator") != "simulator" else "simulator_flow", record["env"]
    fitted = "+test_time_fit" if (record.get("test_time_fit") or {}).get("steps") else ""
    return method, record.get("ablation", "full") + fitted, record["env"]


def pool_runs(records: list[dict]) -> list[dict]:
    """One record per variant, in the order variants first appear. A variant with one run keeps its
    record unchanged; several give a record with ``runs`` (how many), ``checkpoints`` (one entry
    per run), the mean over runs of every number all of them carry, each of those numbers' values
    per run in ``run_values`` (key -> [runs]), and per-video errors (dicts rollout id -> error) averaged per
    video. A spread over videos (``*_std``) is kept only where every run has the same one of the
    same mean (the range midpoint's); a mean of the runs' spreads is no spread of anything.

    Raises ValueError, naming the runs' checkpoints, when the runs were evaluated on different
    test videos: their means would not be comparable."""
    groups: dict[tuple, list[dict]] = {}
    for record in records:
        groups.setdefault(variant(record), []).append(record)
    return [runs[0] if len(runs) == 1 else _pooled(runs) for runs in groups.values()]


def _pooled(runs: list[dict]) -> dict:
    method, ablation, env = variant(runs[0])
    where = [r.get("checkpoints", "?") for r in runs]
    shared = set.intersection(*(set(r) for r in runs))
    for key in sorted(k for k in shared if isinstance(runs[0][k], dict) and k.startswith("per_video_")):
        ids = [set(r[key]) for r in runs]
        if any(i != ids[0] for i in ids):
            raise ValueError(f"{method} {ablation} on {env}: {len(runs)} runs to pool were evaluated on different test videos "
                             f"({key} has {[len(i) for i in ids]} videos, not the same ones); their checkpoints: {where}")
    if len({r.get("n_test") for r in runs}) > 1:
        raise ValueError(f"{method} {ablation} on {env}: {len(runs)} runs to pool have n_test {[r.get('n_test') for r in runs]}; "
                         f"their checkpoints: {where}")
    pooled = {"env": env, "method": method, "ablation": ablation, "runs": len(runs), "checkpoints": where, "run_values": {}}
    for key in sorted(shared - set(pooled)):
        values = [r[key] for r in runs]
        if key.endswith("_std"):  # kept where it describes the same numbers in every run
            if all(v == values[0] and r.get(key[:-4]) == runs[0].get(key[:-4]) for v, r in zip(values, runs)):
                pooled[key] = values[0]
        elif all(isinstance(v, numbers.Real) and not isinstance(v, bool) for v in values):
            pooled["run_values"][key] = [float(v) for v in values]
            pooled[key] = sum(pooled["run_values"][key]) / len(values)
        elif key.startswith("per_video_"):
            pooled[key] = {i: sum(float(v[i]) for v in values) / len(values) for i in values[0]}
        elif all(v == values[0] for v in values):  # e.g. the observation length, the proposals' source
            pooled[key] = values[0]
    return pooled
