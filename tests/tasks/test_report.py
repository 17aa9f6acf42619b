"""task=report: the tables of every evaluation under one folder or a list of folders."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from tests.conftest import REPO
from vgpl.eval.tables import PER_VIDEO
from vgpl.tasks.evaluate import report


def _evaluation(folder: Path, env: str, ablation: str, mae: float, t20: float) -> Path:
    folder.mkdir(parents=True)
    record = {"env": env, "method": "vgpl", "ablation": ablation, "param_mae_pct": mae, "param_mae_pct_std": 1.0,
              **{f"future_mse_x1e4@{t}": t20 * t / 20 for t in (1, 5, 10, 20)},
              PER_VIDEO.format(20): {"900": t20 - 1.0, "901": t20 + 1.0}}
    (folder / "metrics.json").write_text(json.dumps(record))
    return folder


def _report(tmp_path: Path, folders: str) -> dict:
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=["task=report", f"task.dir={folders}", f"paths.output_dir={tmp_path}/report"])
    return report(cfg)


def test_a_list_of_separately_run_evaluations_makes_one_table(tmp_path):
    full = _evaluation(tmp_path / "a/full", "mass_rope", "full", 15.4, 113.4)
    ablated = _evaluation(tmp_path / "b/no_rigidness", "mass_rope", "no_rigidness", 20.0, 150.0)
    out = _report(tmp_path, f"[{full},{ablated}]")
    assert out["n_records"] == 2
    text = (tmp_path / "report/report.md").read_text()
    assert "| VGPL | 15.4% (1.0) |" in text and "| VGPL w/o rigidness (Q = 0) | 20.0% (1.0) |" in text
    assert "113.400" in (tmp_path / "report/table2.csv").read_text()
    paired = (tmp_path / "report/paired_t20.csv").read_text().splitlines()  # the two runs' videos, paired
    assert len(paired) == 2 and paired[1].startswith('mass_rope,VGPL w/o rigidness (Q = 0),2,113.400,150.000,"+36.600 [+36.600, +36.600]",100%')
    assert _report(tmp_path, str(tmp_path))["n_records"] == 2  # one folder: everything under it


def test_a_missing_or_empty_folder_in_the_list_is_named(tmp_path):
    full = _evaluation(tmp_path / "a", "mass_rope", "full", 15.4, 113.4)
    with pytest.raises(ValueError, match=r"task.dir='.*/nowhere': expected the folder of a task=evaluate"):
        _report(tmp_path, f"[{full},{tmp_path}/nowhere]")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match=r"task.dir=.*/empty: no evaluation metrics.json"):
        _report(tmp_path, f"[{full},{tmp_path}/empty]")
    assert not (tmp_path / "report").exists()  # refused before anything is written


def test_two_seeds_of_one_variant_are_pooled_not_overwritten(tmp_path):
    seed0 = _evaluation(tmp_path / "seed0/full", "rigid_fall", "full", 7.0, 100.0)
    seed1 = _evaluation(tmp_path / "seed1/full", "rigid_fall", "full", 8.0, 120.0)
    assert _report(tmp_path, f"[{seed0},{seed1}]")["n_records"] == 2
    text = (tmp_path / "report/report.md").read_text()
    assert "| VGPL | 7.5 ± 0.7% (runs 7.0, 8.0) |" in text and "| rigid_fall | VGPL | 2 | 7.0, 8.0 | 100.0, 120.0 |" in text
    assert "| VGPL | 5.500 ± 0.707 | 27.500 ± 3.536 | 55.000 ± 7.071 | 110.000 ± 14.142 |" in text  # Table 2: the mean ± sd of the two runs
