"""task.modules_at_once: the pipeline trains its inference modules side by side, each in a spawned
process with its share of the threads, for the time their plans take one after the other."""

from __future__ import annotations

import json
import os
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

import vgpl.tasks.pipeline as pipeline_module
import vgpl.tasks.time_budget as time_budget_module
from tests.conftest import REPO
from tests.tasks.test_time_budget import QUICK, Clock
from vgpl.tasks.at_once import run_at_once, threads_each
from vgpl.tasks.stage import trainer_kwargs
from vgpl.tasks.time_budget import TimeBudget, seconds


def threads_and_process(c) -> dict:
    """A stand-in training (importable, so a spawned process can run it)."""
    if c.fail:
        raise ValueError(f"model.inference: {c.name} cannot train")
    torch.set_num_threads(c.threads)
    return {"name": c.name, "threads": torch.get_num_threads(), "pid": os.getpid()}


@pytest.mark.slow  # starts several processes (18 to 21 s on a slow 2-core CPU)
def test_each_config_runs_in_its_own_process_with_its_threads_and_a_failure_is_raised():
    configs = {n: OmegaConf.create({"name": n, "threads": 1, "fail": False}) for n in ("full", "no_rigidness")}
    out = run_at_once(threads_and_process, configs)
    assert [r["name"] for r in out.values()] == list(configs) and all(r["threads"] == 1 for r in out.values())
    assert len({r["pid"] for r in out.values()} | {os.getpid()}) == 3
    configs["no_rigidness"].fail = True
    with pytest.raises(ValueError, match="no_rigidness cannot train"):
        run_at_once(threads_and_process, configs)


def test_threads_are_shared_and_never_below_one():
    assert [threads_each(t, 2) for t in (1, 2, 3, 4, 16)] == [1, 1, 1, 2, 8]


def test_trainings_at_once_get_the_time_their_plans_take_one_after_the_other():
    pair = ["train_inference/full", "train_inference/no_rigidness"]
    for elapsed, expected in ((10.0 + 115.0 + 60.0, 260.0), (45.0 + 135.0 + 70.0, 570.0 - 90.0 - 250.0)):  # generate, prior, visual
        clock = Clock()
        budget = TimeBudget(570.0, QUICK, reserve_s=90.0, floor=0.25, clock=clock)
        budget.max_time("train_dynamics"), budget.max_time("train_visual")
        clock.now += elapsed
        given = budget.max_time_together(pair)
        assert given == pytest.approx(expected)  # late: all that is left, as nothing is planned after them
        assert budget.given[pair[0]] == budget.given[pair[1]] == {"planned_s": 260.0, "max_time_s": round(given, 1), "left_s": 570.0 - 90.0 - elapsed}
        assert budget.shortened(pair[1]) == (given < 260.0)
    assert TimeBudget(None, QUICK).max_time_together(pair) == 260.0
    assert TimeBudget(570.0, {**QUICK, "train_inference/full": None}).max_time_together(pair) is None


def pipeline_with_stand_ins(tmp_path, monkeypatch, *overrides):
    """python run.py (the quick preset) with every step a stand-in, run_at_once run in this
    process on the budget's clock; returns (what each module's stand-in saw and the report's
    notes under "report", pipeline.json)."""
    clock = Clock()
    monkeypatch.setattr(time_budget_module, "time", SimpleNamespace(perf_counter=clock))
    monkeypatch.setattr(pipeline_module, "time", SimpleNamespace(perf_counter=clock))
    seen: dict[str, dict] = {}

    def train(c):
        step = str(Path(c.paths.output_dir).relative_to(tmp_path))
        kwargs = trainer_kwargs(c, c.model.inference)
        seen[step] = {"threads": c.threads, "max_time": seconds(kwargs["max_time"]), "progress_bar": kwargs.get("enable_progress_bar", True),
                      "ablation": c.ablation.name}
        return {"steps": 1, "max_steps": 2, "stopped_by": "max_time", "precision": "32-true"}

    def at_once(fn, configs):
        results = {step: fn(c) for step, c in configs.items()}
        clock.now += max(seen[s]["max_time"] for s in configs)  # side by side: the pair takes one max_time
        return results

    def step(c):
        clock.now += 10.0
        return {"steps": 1, "max_steps": 1, "stopped_by": "max_steps", "precision": "32-true"}

    for name in ("generate", "train_dynamics", "train_visual", "export_proposals"):
        monkeypatch.setattr(pipeline_module, name, step)
    monkeypatch.setattr(pipeline_module, "check_identifiability", lambda c: {"skipped": True})
    monkeypatch.setattr(pipeline_module, "train_inference", train)
    monkeypatch.setattr(pipeline_module, "run_at_once", at_once)
    monkeypatch.setattr(pipeline_module, "evaluate", lambda c: {"ablation": c.ablation.name})
    monkeypatch.setattr(pipeline_module, "write_tables", lambda records, out, text: seen.setdefault("report", text))
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=[f"paths.output_dir={tmp_path}", *overrides])
    pipeline_module.pipeline(cfg)
    return seen, json.loads((tmp_path / "pipeline.json").read_text())


def test_the_quick_preset_trains_its_two_modules_side_by_side_on_one_thread_each(tmp_path, monkeypatch):
    seen, summary = pipeline_with_stand_ins(tmp_path, monkeypatch, "task.time_budget.total=00:00:10:00")  # on time: the plans' own caps
    report = seen.pop("report")
    assert "- train_inference/full: 1 of 2 steps, 260 s side by side with train_inference/no_rigidness **stopped by" in report
    assert seen == {f"train_inference/{a}": {"threads": 1, "max_time": 260.0, "progress_bar": False, "ablation": a} for a in ("full", "no_rigidness")}
    assert summary["times_s"]["train_inference/full"] == summary["times_s"]["train_inference/no_rigidness"] == 260.0
    assert summary["trained"]["train_inference/full"]["planned_s"] == 260.0


@pytest.mark.parametrize("override", ["threads=1", "task.modules_at_once=false"])
def test_without_a_thread_for_each_module_they_train_one_after_the_other(tmp_path, monkeypatch, override):
    seen, summary = pipeline_with_stand_ins(tmp_path, monkeypatch, override, "task.time_budget.total=00:00:10:00")
    assert "side by side" not in seen.pop("report")
    threads = 1 if override == "threads=1" else 2
    assert seen == {f"train_inference/{a}": {"threads": threads, "max_time": 130.0, "progress_bar": True, "ablation": a} for a in ("full", "no_rigidness")}
    assert summary["times_s"]["train_inference/full"] == 0.0  # the stand-in takes no time on its own: nothing ran beside it
