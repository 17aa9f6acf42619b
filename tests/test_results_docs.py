"""The results tables of README.md and docs/results.md are rendered from results/*.jsonl: a number
edited by hand, or data changed without re-rendering, fails here."""

from __future__ import annotations

import json

import pytest
from hydra import compose, initialize_config_dir

from tests.conftest import REPO
from vgpl.results import BLOCK, env_table, read_results, stale_blocks
from vgpl.tasks.results import results

DOCS = (REPO / "README.md", REPO / "docs" / "results.md")


def task_config(**task):
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        return compose("config", overrides=["task=results", *(f"task.{k}={v}" for k, v in task.items())])


def run_row(env: str, seed: int, mae: float, midpoint: float, **more) -> dict:
    full = {"param_mae_pct": mae, "midpoint_param_mae_pct": midpoint, **more}
    return {"env": env, "preset": "quick", "overrides": [f"env={env}", f"seed={seed}"], "wall_s": 500.0 + seed,
            "evaluate": {"full": full, "no_rigidness": {"param_mae_pct": 2 * mae, "midpoint_param_mae_pct": midpoint}},
            "machine": {"cores": 2, "cpu": "Test CPU", "cpu_generation": "family 1 model 2", "torch": "2.13.0+cpu", "code": "abc1234"}}


def test_the_docs_tables_are_their_results_data():
    rows = read_results(REPO / "results")
    readme = DOCS[0].read_text()
    assert {m["name"] for m in BLOCK.finditer(readme)} == {"rigid_fall", "mass_rope", "fluid_cube"}
    for doc in DOCS:
        assert stale_blocks(doc.read_text(), rows) == [], f"{doc.name}: run python run.py task=results"


def test_a_number_edited_by_hand_fails_the_check_and_a_render_restores_it(tmp_path):
    original = DOCS[0].read_text()
    block = next(BLOCK.finditer(original))
    edited_body = block["body"].replace("25.7%", "24.7%", 1)
    assert edited_body != block["body"]
    copy = tmp_path / "README.md"
    copy.write_text(original[: block.start("body")] + edited_body + original[block.end("body"):])
    edited = copy.read_text()
    with pytest.raises(ValueError, match=block["name"]):
        results(task_config(dir=REPO / "results", docs=f"[{copy}]", check="true"))
    assert copy.read_text() == edited  # the check writes nothing
    summary = results(task_config(dir=REPO / "results", docs=f"[{copy}]"))
    assert summary["rewritten"] == [str(copy)] and copy.read_text() == original


def test_a_presets_row_is_the_mean_and_sd_of_its_runs():
    future = {f"future_mse_x1e4@{k}": v for k, v in zip((1, 5, 10, 20), (1.0, 2.0, 30.0, 400.0))}
    runs = [run_row("mass_rope", s, mae, 25.0, refine_mse_x1e4_before=8.0, refine_mse_x1e4_after=4.0, **future)
            for s, mae in enumerate((10.0, 20.0, 30.0))]
    paper = {"source": "paper", "env": "mass_rope", "method": "vgpl", "param_mae_pct": 2.9, "param_mae_pct_std": 1.3}
    table = env_table([*runs, paper], "mass_rope")
    row = next(line for line in table.splitlines() if line.startswith("| `python run.py env=mass_rope seed=<s>`"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells == ["`python run.py env=mass_rope seed=<s>`, s = 0, 1, 2 [m1]", "20.0 ± 10.0%", "10.0, 20.0, 30.0",
                     "25.0% (0.80 ± 0.40)", "40.0 ± 20.0%", "", "1.00 / 2.00 / 30.0 / 400", "8.00 -> 4.00"]
    assert "| paper, VGPL | 2.9% (1.3) |" in table
    for run, mae in zip(runs, (2.0, 4.0, 6.0)):  # DensePhysNet in the same runs: its own column
        run["evaluate"]["densephysnet"] = {"param_mae_pct": mae, "midpoint_param_mae_pct": 25.0}
    row = next(line for line in env_table(runs, "mass_rope").splitlines() if line.startswith("| `python run.py env=mass_rope"))
    assert [c.strip() for c in row.strip("|").split("|")][5] == "4.0 ± 2.0%"
    assert "[m1] 3 runs from nothing (quick preset): 2-core Test CPU (family 1 model 2), torch 2.13.0+cpu; commit abc1234; 8.3-8.4 min a run." in table


def test_a_bad_results_line_is_named_with_its_file_and_line(tmp_path):
    (tmp_path / "runs.jsonl").write_text(json.dumps(run_row("rigid_fall", 0, 5.0, 25.0)) + "\n{not json\n")
    with pytest.raises(ValueError, match=r"runs\.jsonl, line 2: not a JSON object"):
        read_results(tmp_path)
    (tmp_path / "runs.jsonl").write_text(json.dumps({"env": "rigid_fall"}) + "\n")
    with pytest.raises(ValueError, match=r"runs\.jsonl, line 1: a row needs 'env', and 'preset'"):
        read_results(tmp_path)


def test_readmes_tables_keep_the_rows_run_over_three_seeds_and_results_md_lists_every_run():
    """A preset run once is a single draw: the plain block leaves it out, the /all block shows it
    with its footnote saying one run."""
    seeded = [run_row("rigid_fall", s, mae, 25.0) for s, mae in enumerate((10.0, 12.0, 14.0))]
    once = {**run_row("rigid_fall", 0, 8.0, 25.0), "preset": "standard"}
    plain, every = env_table([*seeded, once], "rigid_fall"), env_table([*seeded, once], "rigid_fall/all")
    assert "experiment=standard" not in plain and "| `python run.py env=rigid_fall seed=<s>`, s = 0, 1, 2 [r1] | 12.0 ± 2.0%" in plain
    assert "| `python run.py experiment=standard env=rigid_fall seed=<s>`, s = 0 [r2] | 8.0% |" in every
    assert "[r2] 1 run from nothing (standard preset)" in every
    with pytest.raises(ValueError, match="results table 'rigid_fall/some'"):
        env_table(seeded, "rigid_fall/some")
