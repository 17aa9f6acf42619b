"""Table 1 (parameter estimation) and Table 2 (future prediction) from evaluation records, as
Markdown and CSV. A record is one evaluation's metrics.json: env, method, ablation, metrics."""

from __future__ import annotations

import csv
import io
import re
import statistics
from pathlib import Path
from typing import NamedTuple

import torch

from vgpl.eval.paired import paired_bootstrap, paired_values
from vgpl.eval.pooled import pool_runs, variant
from vgpl.metrics import rms_mm
from vgpl.models.rollout import FUTURE

ENVS = ("mass_rope", "rigid_fall", "fluid_cube")  # the paper's column order
HORIZONS = (1, 5, 10, 20)
ROWS = {  # (method, ablation) -> row name, in the paper's order
    ("densephysnet", "simulator_flow"): "DensePhysNet (simulator flow, privileged)",
    ("densephysnet", "full"): "DensePhysNet",
    ("vgpl", "no_rigidness_unconstrained"): "VGPL w/o rigidness (unconstrained prior)",
    ("vgpl", "no_rigidness"): "VGPL w/o rigidness (Q = 0)",
    ("vgpl", "no_refinement"): "VGPL w/o refinement",
    ("vgpl", "no_params"): "VGPL w/o parameter estimation",
    ("vgpl", "full"): "VGPL",
    ("vgpl", "full+test_time_fit"): "VGPL + test-time fit",
}
TABLE1_ROWS = [("densephysnet", "simulator_flow"), ("densephysnet", "full"), ("vgpl", "no_rigidness_unconstrained"), ("vgpl", "no_rigidness"), ("vgpl", "full"),
                ("vgpl", "full+test_time_fit")]
TABLE2_ROWS = [("vgpl", "no_rigidness_unconstrained"), ("vgpl", "no_rigidness"), ("vgpl", "no_refinement"), ("vgpl", "no_params"), ("vgpl", "full"),
               ("vgpl", "full+test_time_fit")]
PER_VIDEO = "per_video_" + FUTURE  # record key: {rollout id (str): that video's MSE x 1e4 at T+k}


def _key(record: dict) -> tuple[str, str]:
    return variant(record)[:2]


def _index(records: list[dict]) -> dict:
    """(method, ablation, env) -> its record; several runs of one variant are pooled (vgpl.eval.pooled)."""
    return {variant(r): r for r in pool_runs(records)}


def _envs(records: list[dict]) -> list[str]:
    present = {r["env"] for r in records}
    return [e for e in ENVS if e in present] + sorted(present - set(ENVS))


def _method_rows(records: list[dict], keys: list[tuple[str, str]], cells) -> list[list[str]]:
    """One row per (method, ablation) in ``keys`` that has any record: its name, then
    ``cells(record or None)`` (a list of strings) for every env in turn."""
    index, envs = _index(records), _envs(records)
    return [[ROWS[key], *[c for e in envs for c in cells(index.get((*key, e)))]]
            for key in keys if any((*key, e) in index for e in envs)]


MIDPOINT_ROW = "range midpoint (constant guess)"


def mean_sd(values: list[float], unit: str = "", digits: int = 1) -> str:
    """"7.5 ± 0.7%": the mean ± sd of ``values`` (a single value alone), ``digits`` decimals."""
    if len(values) == 1:
        return f"{values[0]:.{digits}f}{unit}"
    return f"{statistics.mean(values):.{digits}f} ± {statistics.stdev(values):.{digits}f}{unit}"


def _mae_cell(record: dict | None, key: str = "param_mae_pct") -> str:
    """"7.0% (5.4)": the MAE and its std over videos; for pooled runs the mean ± sd over the runs
    and each run's, "7.2 ± 0.3% (runs 7.0, 7.4)"."""
    if record is None or key not in record:
        return ""
    if f"{key}_std" in record:
        return f"{record[key]:.1f}% ({record[f'{key}_std']:.1f})"
    runs = record["run_values"][key]
    return f"{mean_sd(runs, '%')} (runs {', '.join(f'{v:.1f}' for v in runs)})"


def table1_rows(records: list[dict]) -> tuple[list[str], list[list[str]]]:
    """Header and rows: parameter MAE as % of range, std in parentheses. The first row is the
    constant guess at the middle of each range on the same test videos (``midpoint_param_mae_pct``
    of the env's VGPL records), the floor every estimate should beat; absent for older records."""
    envs = _envs(records)
    rows = _method_rows(records, TABLE1_ROWS, lambda r: [_mae_cell(r)])
    floors = {r["env"]: r for r in records if "midpoint_param_mae_pct" in r}
    if floors:
        rows.insert(0, [MIDPOINT_ROW, *[_mae_cell(floors.get(e), "midpoint_param_mae_pct") for e in envs]])
    return ["method", *envs], rows


def table2_rows(records: list[dict]) -> tuple[list[str], list[list[str]]]:
    """Header and rows: future MSE x 1e4 at T+1, 5, 10, 20, per env."""
    cells = lambda r: [_future_cell(r, FUTURE.format(k)) for k in HORIZONS]  # noqa: E731
    return ["method"] + [f"{e} T+{k}" for e in _envs(records) for k in HORIZONS], _method_rows(records, TABLE2_ROWS, cells)


def _future_cell(record: dict | None, key: str) -> str:
    """"4.329": a future MSE x 1e4; for pooled runs the mean ± sd over the runs, "4.329 ± 0.210"."""
    if record is None or key not in record:
        return ""
    runs = record.get("run_values", {}).get(key)
    return mean_sd(runs, digits=3) if runs else f"{record[key]:.3f}"


def _mse(value, sign: str = "") -> str:
    """An MSE x 1e4 as Table 2 prints it, in exponent form once a rollout has diverged."""
    value = float(value)
    return f"{value:{sign}.3f}" if abs(value) < 1e5 else f"{value:{sign}.3e}"


def _p_value(p: float) -> str:
    """A p-value in two significant figures, or an upper bound once it is below 1e-4."""
    return f"{p:.2g}" if p >= 1e-4 else "< 1e-4"


MEAN_DIFFERENCE, LOWER_SHARE, VERDICT = "mean difference (ablation - VGPL) [95% bootstrap]", "videos where VGPL is lower (sign test p)", "VGPL is"


def paired_rows(records: list[dict], step: int) -> tuple[list[str], list[list[str]]]:
    """Header and rows: per env, each ablation against VGPL at T+``step`` on the videos both
    evaluated (records with per-video errors, ``PER_VIDEO``): the means, the mean difference with
    its 95% bootstrap interval, how often VGPL is the lower (with the sign test's p), the medians, and
    the verdict: the mean's (Table 2's statistic), and where the mean ties but the sign test does
    not (p < 0.05), which way most videos go."""
    key = PER_VIDEO.format(step)
    index = _index([r for r in records if key in r])
    rows = []
    for env in _envs(records):
        full = index.get(("vgpl", "full", env))
        for name in (row for row in TABLE2_ROWS if row != ("vgpl", "full")):  # each ablation, and the test-time fit
            other = index.get((*name, env))
            ids, a, b = paired_values(full[key], other[key]) if full and other else ([], None, None)
            if not ids:
                continue
            s = paired_bootstrap(a, b)
            verdict = "lower" if s["low"] > 0 else "higher" if s["high"] < 0 else "not distinguishable"
            if verdict == "not distinguishable" and s["sign_p"] < 0.05:  # the mean ties; the typical video does not
                verdict += f" in the mean; {'lower' if s['reference_lower_share'] > 0.5 else 'higher'} on most videos"
            rows.append([env, ROWS[name], str(len(ids)), _mse(a.mean()), _mse(b.mean()),
                         f"{_mse(s['mean_diff'], '+')} [{_mse(s['low'], '+')}, {_mse(s['high'], '+')}]",
                         f"{100 * s['reference_lower_share']:.0f}% (p {_p_value(s['sign_p'])})", f"{_mse(a.median())} / {_mse(b.median())}", verdict])
    header = ["env", "ablation", "videos", f"VGPL T+{step}", f"ablation T+{step}", MEAN_DIFFERENCE, LOWER_SHARE, "medians (VGPL / ablation)", VERDICT]
    return header, rows


def paired_steps(records: list[dict]) -> list[int]:
    """The T+k of every per-video error the records carry."""
    pattern = re.compile(re.escape(PER_VIDEO.format("")) + r"(\d+)$")
    return sorted({int(m.group(1)) for r in records for k in r if (m := pattern.match(k))})


def paired_tables(records: list[dict]) -> dict[int, tuple[list[str], list[list[str]]]]:
    """``paired_rows`` at every T+k the records carry per-video errors for, where any pair exists
    (each is a bootstrap: computed once for report.md and the CSV)."""
    tables = {step: paired_rows(records, step) for step in paired_steps(records)}
    return {step: table for step, table in tables.items() if table[1]}


PAIRED_HEADING = ("## Is VGPL lower than each ablation? The same test videos, paired: the mean difference (ablation - VGPL) "
                  "[95% bootstrap], then on how many videos VGPL is lower (sign test p)")


def paired_by_horizon(paired: dict[int, tuple[list[str], list[list[str]]]]) -> tuple[list[str], list[list[str]]]:
    """The per-horizon tables of ``paired_tables`` folded into one, ablation by horizon: a row per
    (env, ablation), a column per T+k whose cell is the verdict, the mean difference with its
    interval and the share of videos where VGPL is lower. The per-horizon CSVs keep the rest."""
    steps = sorted(paired)
    cells: dict[tuple[str, str], dict[int, str]] = {}
    videos: dict[tuple[str, str], str] = {}
    for step in steps:
        header, rows = paired[step]
        col = {name: header.index(name) for name in header}
        for row in rows:
            key = (row[0], row[1])
            videos.setdefault(key, row[col["videos"]])
            cells.setdefault(key, {})[step] = f"{row[col[VERDICT]]}: {row[col[MEAN_DIFFERENCE]]}; {row[col[LOWER_SHARE]]}"
    return (["env", "ablation", "videos", *(f"T+{k}" for k in steps)],
            [[env, name, videos[(env, name)], *(cells[(env, name)].get(k, "") for k in steps)] for env, name in cells])


def markdown(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def param_rows(names: list[str], truth, inferred, rollout_ids=None, columns: dict | None = None) -> tuple[list[str], list[list[str]]]:
    """params.csv of an evaluation: one row per test video with its true and inferred value of each
    parameter (truth, inferred [R, P] physical; rollout_ids [R], default 0 .. R - 1), then one
    column per entry of ``columns`` (name -> [R] values, e.g. the video's future MSE)."""
    ids = list(range(len(truth))) if rollout_ids is None else [int(i) for i in rollout_ids]
    columns = columns or {}
    header = ["rollout_id"] + [f"{kind}_{n}" for n in names for kind in ("true", "inferred")] + list(columns)
    rows = [[str(i)] + [f"{float(v):.6g}" for p in range(len(names)) for v in (t[p], x[p])] + [f"{float(c[r]):.6g}" for c in columns.values()]
            for r, (i, t, x) in enumerate(zip(ids, truth, inferred))]
    return header, rows


class ParamsCsv(NamedTuple):
    """An evaluation's params.csv read back from ``path``: rollout_ids [R]; truth, inferred [R, P]
    physical, in the order of the names asked for; columns: name -> [R] of each extra column asked for."""

    path: str
    rollout_ids: list[int]
    truth: torch.Tensor
    inferred: torch.Tensor
    columns: dict[str, torch.Tensor]

    def select(self, rollout_ids) -> ParamsCsv:
        """The rows of ``rollout_ids``, in their order; ValueError names the ids with no row."""
        row = {i: r for r, i in enumerate(self.rollout_ids)}
        missing = [int(i) for i in rollout_ids if int(i) not in row]
        if missing:
            raise ValueError(f"{self.path}: no row for rollouts {missing[:5]}{'...' if len(missing) > 5 else ''}: "
                             "expected a params.csv of task=evaluate on the same test split")
        keep = [row[int(i)] for i in rollout_ids]
        return ParamsCsv(self.path, [int(i) for i in rollout_ids], self.truth[keep], self.inferred[keep], {c: v[keep] for c, v in self.columns.items()})


def read_params_csv(path, names: list[str], columns: tuple[str, ...] = ()) -> ParamsCsv:
    """The inverse of ``param_rows``: an evaluation's params.csv with the true and inferred value of
    each of ``names`` and the extra ``columns``. One ValueError names the file and what is missing."""
    try:
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
    except FileNotFoundError:
        raise ValueError(f"{path}: no such file (the params.csv of a task=evaluate output folder was expected)") from None
    if not rows:
        raise ValueError(f"{path}: no rows (one per test video was expected)")
    needed = ["rollout_id"] + [f"{kind}_{n}" for n in names for kind in ("true", "inferred")] + list(columns)
    missing = [k for k in needed if k not in rows[0]]
    if missing:
        raise ValueError(f"{path}: columns {missing} missing (found {list(rows[0])}): is it another env's params.csv?")
    truth, inferred = (torch.tensor([[float(r[f"{kind}_{n}"]) for n in names] for r in rows]) for kind in ("true", "inferred"))
    return ParamsCsv(str(path), [int(r["rollout_id"]) for r in rows], truth, inferred, {c: torch.tensor([float(r[c]) for r in rows]) for c in columns})


def runs_rows(pooled: list[dict]) -> tuple[list[str], list[list[str]]]:
    """Header and rows: each pooled variant's run count, and each run's parameter MAE and T+20."""
    cell = lambda r, k: ", ".join(f"{v:.1f}" for v in r["run_values"].get(k, []))  # noqa: E731
    return (["env", "method", "runs", "parameter MAE % per run", "T+20 per run"],
            [[r["env"], ROWS[_key(r)], str(r["runs"]), cell(r, "param_mae_pct"), cell(r, FUTURE.format(20))] for r in pooled])


def csv_text(header: list[str], rows: list[list[str]]) -> str:
    buf = io.StringIO()
    csv.writer(buf).writerows([header, *rows])
    return buf.getvalue()


def report_markdown(records: list[dict], paired: dict | None = None) -> str:
    """Table 1, Table 2, refinement, rigidness, the pooled runs and the paired table, ablation by
    horizon (``paired_by_horizon`` of ``paired_tables(records)`` unless given), as Markdown."""
    records = pool_runs(records)
    parts = ["## Table 1: parameter estimation, MAE as % of the range (std)", markdown(*table1_rows(records)),
             "", "## Table 2: future prediction, MSE x 1e4 after T+k steps", markdown(*table2_rows(records))]
    order = {env: k for k, env in enumerate(_envs(records))}  # the paper's env order, as in Tables 1 and 2
    extra = sorted((r for r in records if "refine_mse_x1e4_before" in r and _key(r) == ("vgpl", "full")), key=lambda r: order[r["env"]])
    if extra:
        parts += ["", "## Refinement: position MSE x 1e4 of the observed frames (RMS per coordinate, mm)", markdown(
            ["env", "before (proposals)", "after (refined)"],
            [[r["env"], *(f"{r[f'refine_mse_x1e4_{w}']:.3f} ({rms_mm(r[f'refine_mse_x1e4_{w}']):.1f} mm)" for w in ("before", "after"))]
             for r in extra])]
        rig = [(r["env"], k.split("/", 1)[1], v) for r in extra for k, v in r.items() if k.startswith("rigidness_prob@")]
        if rig:
            parts += ["", "## Rigidness: probability of the correct label at the trained T", markdown(
                ["env", "object type", "P(correct)"], [[e, t, f"{v:.3f}"] for e, t, v in rig])]
    pooled = [r for r in records if r.get("runs", 1) > 1]
    if pooled:
        parts += ["", "## Runs pooled: the tables above give their mean, the paired table each video's mean over runs",
                  markdown(*runs_rows(pooled))]
    paired = paired_tables(records) if paired is None else paired
    if paired:
        parts += ["", PAIRED_HEADING, markdown(*paired_by_horizon(paired))]
    return "\n".join(parts) + "\n"


def write_tables(records: list[dict], out: Path, notes: str = "") -> str:
    """report.md (the tables, then ``notes``), table1.csv, table2.csv and, where records carry
    per-video errors, paired_t<k>.csv in ``out``; returns the Markdown."""
    out.mkdir(parents=True, exist_ok=True)
    paired = paired_tables(records)  # each ablation against VGPL on the same videos
    text = report_markdown(records, paired) + notes
    (out / "report.md").write_text(text)
    (out / "table1.csv").write_text(csv_text(*table1_rows(records)))
    (out / "table2.csv").write_text(csv_text(*table2_rows(records)))
    for step, table in paired.items():
        (out / f"paired_t{step}.csv").write_text(csv_text(*table))
    return text
