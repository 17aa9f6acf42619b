"""Results tables rendered from data: the tables of README.md and docs/results.md come from the JSON
lines under ``results/``, re-rendered by ``python run.py task=results`` and checked by a test, so a
number in the docs is always its data's.

A docs file marks each rendered table with ``<!-- results:<env> -->`` ... ``<!-- /results -->``: the
env's runs of each preset run over at least ``MIN_RUNS`` seeds, every number a mean ± sd over the
runs (one per seed), then the paper's rows; ``<!-- results:<env>/all -->`` also shows the presets
run fewer times (README.md's tables have no single-draw row, docs/results.md's list every run). Two kinds of row, one JSON object per line:

- a run: the line ``benchmarks/main_job.py`` prints (``env``, ``overrides`` with ``seed=<s>``,
  ``wall_s``, each ablation's metrics under ``evaluate``, ``machine`` with the code's commit), with
  ``preset`` added, and optionally a ``note`` the row's footnote repeats;
- the paper: ``{"source": "paper", "env", "method": "vgpl" | "densephysnet", "param_mae_pct",
  "param_mae_pct_std", "future_mse_x1e4": {"1": ..}, "refine_mse_x1e4": [before, after]}``.
"""

from __future__ import annotations

import json
import re
import statistics
from collections import defaultdict
from pathlib import Path

from vgpl.eval.tables import markdown, mean_sd

BLOCK = re.compile(r"<!-- results:(?P<name>[\w/]+) -->\n(?P<body>.*?)<!-- /results -->", re.S)
HORIZONS = ("1", "5", "10", "20")
PARAM = {"rigid_fall": "gravity", "mass_rope": "stiffness", "fluid_cube": "viscosity"}
MIN_RUNS = 3  # seeds a row needs in a plain <env> block


def read_results(folder: Path) -> list[dict]:
    """Every row of the ``*.jsonl`` files in ``folder``, in file and line order."""
    files = sorted(Path(folder).glob("*.jsonl"))
    if not files:
        raise FileNotFoundError(f"results folder {folder}: no *.jsonl files")
    rows = []
    for path in files:
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if not line.strip():
                continue
            try:
                row = json.loads(line)
            except json.JSONDecodeError as e:
                raise ValueError(f"{path}, line {number}: not a JSON object ({e.msg})") from e
            if "env" not in row or row.get("source") != "paper" and "preset" not in row:
                raise ValueError(f"{path}, line {number}: a row needs 'env', and 'preset' unless its source is 'paper'")
            rows.append(row)
    return rows


def _seed(row: dict) -> str:
    return next((o.split("=", 1)[1] for o in row.get("overrides", []) if o.startswith("seed=")), "0")


def _command(row: dict) -> str:
    rest = [o for o in row.get("overrides", []) if not o.startswith(("seed=", "experiment="))]  # the preset names its own
    preset = [] if row["preset"] == "quick" else [f"experiment={row['preset']}"]
    return " ".join(["python run.py", *preset, *rest, "seed=<s>"])


def _three(value: float) -> str:
    """Three significant figures, at most three decimals."""
    digits = max(0, min(3, 2 - int(f"{abs(value):e}".split("e")[1])))
    return f"{value:.{digits}f}"


def _runs_row(runs: list[dict], key: str) -> list[str]:
    """One table row over ``runs`` of one preset: the full model's numbers, mean ± sd over the runs,
    and DensePhysNet's where every run evaluated it."""
    full = [r["evaluate"]["full"] for r in runs]
    mae = [m["param_mae_pct"] for m in full]
    midpoint = statistics.mean(m["midpoint_param_mae_pct"] for m in full)
    ratio = [m["param_mae_pct"] / m["midpoint_param_mae_pct"] for m in full]
    no_rigid = [r["evaluate"]["no_rigidness"]["param_mae_pct"] for r in runs if "no_rigidness" in r["evaluate"]]
    baseline = [r["evaluate"]["densephysnet"]["param_mae_pct"] for r in runs if "densephysnet" in r["evaluate"]]
    future = refine = ""
    if all(f"future_mse_x1e4@{k}" in m for m in full for k in HORIZONS):
        future = " / ".join(_three(statistics.mean(m[f"future_mse_x1e4@{k}"] for m in full)) for k in HORIZONS)
    if all("refine_mse_x1e4_before" in m for m in full):
        refine = " -> ".join(_three(statistics.mean(m[f"refine_mse_x1e4_{w}"] for m in full)) for w in ("before", "after"))
    cells = [f"`{_command(runs[0])}`, s = {', '.join(_seed(r) for r in runs)} [{key}]", mean_sd(mae, "%"),
             ", ".join(f"{v:.1f}" for v in mae), f"{midpoint:.1f}% ({mean_sd(ratio, digits=2)})",
             mean_sd(no_rigid, "%") if len(no_rigid) == len(runs) else "", mean_sd(baseline, "%") if len(baseline) == len(runs) else "",
             future, refine]
    return cells


def _machine(runs: list[dict]) -> str:
    m = runs[0]["machine"]
    cpus = {f"{r['machine']['cores']}-core {r['machine']['cpu']} ({r['machine']['cpu_generation']})" for r in runs}
    commits = sorted({r["machine"]["code"] or "unknown" for r in runs})
    walls = [r["wall_s"] / 60 for r in runs]
    span = f"{walls[0]:.1f} min" if len(walls) == 1 else f"{min(walls):.1f}-{max(walls):.1f} min a run"
    return f"{'; '.join(sorted(cpus))}, torch {m['torch']}; commit {', '.join(commits)}; {span}"


def env_table(rows: list[dict], name: str) -> str:
    """The markdown table of block ``name`` (``<env>`` or ``<env>/all``): one row per preset and
    overrides (its runs over seeds; ``<env>`` alone keeps those with at least ``MIN_RUNS`` runs), then
    the paper's DensePhysNet and VGPL; footnotes give each row's command, machine and commit."""
    env, _, scope = name.partition("/")
    if env not in PARAM or scope not in ("", "all"):
        raise ValueError(f"results table '{name}': expected <env> or <env>/all, env one of {sorted(PARAM)}")
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for row in rows:
        if row["env"] == env and row.get("source") != "paper":
            groups[(row["preset"], tuple(o for o in row.get("overrides", []) if not o.startswith("seed=")))].append(row)
    header = ["run", f"{PARAM[env]} MAE, mean ± sd", "per run", "range midpoint (MAE / midpoint)", "w/o rigidness",
              "DensePhysNet", "T+1 / 5 / 10 / 20", "refinement"]
    shown = [(key, runs) for key, runs in sorted(groups.items(), key=lambda item: item[0]) if scope == "all" or len(runs) >= MIN_RUNS]
    table, notes = [], []
    for k, (_, runs) in enumerate(shown, 1):
        key = f"{env[0]}{k}"
        table.append(_runs_row(runs, key))
        extra = "".join(f" {n}." for n in sorted({r["note"] for r in runs if r.get("note")}))
        notes.append(f"[{key}] {len(runs)} run{'s' if len(runs) > 1 else ''} from nothing ({runs[0]['preset']} preset): {_machine(runs)}.{extra}")
    for method, label in (("densephysnet", "DensePhysNet"), ("vgpl", "VGPL")):
        for row in rows:
            if row["env"] == env and row.get("source") == "paper" and row["method"] == method:
                future = " / ".join(str(row["future_mse_x1e4"].get(k, "-")) for k in HORIZONS) if row.get("future_mse_x1e4") else ""
                refine = " -> ".join(str(v) for v in row["refine_mse_x1e4"]) if row.get("refine_mse_x1e4") else ""
                table.append([f"paper, {label}", f"{row['param_mae_pct']}% ({row['param_mae_pct_std']})", "", "", "", "", future, refine])
    return markdown(header, table) + "\n\n" + "\n".join(notes) + ("\n" if notes else "")


def render(text: str, rows: list[dict], source: str = "text") -> str:
    """``text`` with every results block re-rendered from ``rows``."""
    if text.count("<!-- results:") != len(BLOCK.findall(text)):
        raise ValueError(f"{source}: a '<!-- results:<name> -->' block has no '<!-- /results -->' line after it")
    return BLOCK.sub(lambda m: f"<!-- results:{m['name']} -->\n{env_table(rows, m['name'])}<!-- /results -->", text)


def stale_blocks(text: str, rows: list[dict]) -> list[str]:
    """Names of the blocks of ``text`` whose table differs from what ``rows`` render."""
    return [m["name"] for m in BLOCK.finditer(text) if m["body"] != env_table(rows, m["name"])]
