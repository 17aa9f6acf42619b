"""task.time_budget: a pipeline whose untimed steps ran late gives its trainings less time, in
proportion to their planned max_time, so that the whole run keeps its total (the quick preset's
10 minutes on a slow VM); one on time is left as it was."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import pytest
from hydra import compose, initialize_config_dir

import vgpl.tasks.pipeline as pipeline_module
import vgpl.tasks.time_budget as time_budget_module
from tests.conftest import REPO
from vgpl.tasks.stage import trainer_kwargs
from vgpl.tasks.time_budget import TimeBudget, scaled_max_time, seconds

# the quick preset's trainings, planned max_time in s, in the pipeline's order
QUICK = {"train_dynamics": 150.0, "train_visual": 75.0, "train_inference/full": 130.0, "train_inference/no_rigidness": 130.0}
# a plan the replayed runs below share with a measured fp32 main job (its own preset's plan then)
PLANNED = {"train_dynamics": 150.0, "train_visual": 60.0, "train_inference/full": 120.0, "train_inference/no_rigidness": 120.0}


class Clock:
    """A wall clock the test moves by hand."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_max_time_is_parsed_as_lightnings_timer_parses_it():
    assert seconds("00:00:09:30") == 570.0
    assert seconds("01:02:00:05") == 86400 + 7200 + 5
    assert seconds({"minutes": 2, "seconds": 0.5}) == 120.5
    assert seconds(None) is None


@pytest.mark.parametrize("bad", ["9:30", {"minutes": "x"}, 570])
def test_a_duration_lightning_cannot_read_is_refused_by_its_key_before_the_pipeline_starts(tmp_path, bad):
    with pytest.raises(ValueError, match=r"task.time_budget.total=.*expected a duration as trainer.max_time takes it"):
        seconds(bad, "task.time_budget.total")
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=[f"paths.root_dir={tmp_path / 'root'}", f"paths.output_dir={tmp_path / 'run'}",
                                           "task.time_budget.total=9:30"])
    with pytest.raises(ValueError, match=r"task.time_budget.total='9:30'"):
        pipeline_module.pipeline(cfg)
    assert not (tmp_path / "root").exists()  # nothing generated


def test_a_training_keeps_its_plan_when_the_plan_fits_and_its_share_when_it_does_not():
    assert scaled_max_time(150.0, ahead_s=450.0, left_s=463.5, floor=0.25) == 150.0
    assert scaled_max_time(60.0, ahead_s=300.0, left_s=282.5, floor=0.25) == pytest.approx(56.5)
    assert scaled_max_time(60.0, ahead_s=300.0, left_s=-40.0, floor=0.25) == 15.0  # past the budget: the floor


def test_a_late_run_catches_up_in_its_trainings_and_ends_within_its_total():
    """The fp32 VM's main job of (generate 46.5 s, the prior 7 s past its max_time, the
    identifiability sweep 24 s, ...) replayed on the budget's clock: 9 min 30 s less 60 s reserved."""
    clock = Clock()
    budget = TimeBudget(570.0, PLANNED, reserve_s=60.0, floor=0.25, clock=clock)
    clock.now += 46.5                                        # generate
    assert budget.max_time("train_dynamics") == 150.0       # 463.5 s left for 450 s planned: on time
    clock.now += 157.0 + 24.0                                # the prior, the identifiability sweep
    visual = budget.max_time("train_visual")
    assert visual == pytest.approx(60.0 * 282.5 / 300.0)     # 282.5 s left for 300 s planned
    clock.now += visual + 4.0 + 3.0                          # its overrun, export_proposals
    full = budget.max_time("train_inference/full")
    assert full == pytest.approx(120.0 * (570 - 60 - (46.5 + 181 + visual + 7)) / 240.0)
    clock.now += full + 4.0
    last = budget.max_time("train_inference/no_rigidness")
    assert last == pytest.approx(570 - 60 - (clock.now - 1000.0))
    assert clock.now - 1000.0 + last + 4.0 + 30.0 < 570.0    # its overrun and the evaluations fit
    assert budget.given["train_visual"] == {"planned_s": 60.0, "max_time_s": round(visual, 1), "left_s": 282.5}


def test_without_a_total_or_a_clock_every_training_keeps_its_own_max_time():
    clock = Clock()
    off = TimeBudget(None, PLANNED, reserve_s=60.0, floor=0.25, clock=clock)
    clock.now += 10_000.0
    assert [off.max_time(s) for s in PLANNED] == list(PLANNED.values()) and off.given == {}
    assert not any(off.shortened(s) for s in PLANNED)
    stepped = TimeBudget(100.0, {"train_baseline": None, "train_visual": 60.0}, floor=0.25, clock=clock)
    clock.now += 70.0
    assert stepped.max_time("train_baseline") is None  # trains by steps: not shortened, not counted
    assert stepped.max_time("train_visual") == 30.0
    assert stepped.shortened("train_visual") and not stepped.shortened("train_baseline")


def test_a_task_config_from_before_the_budget_keeps_every_trainings_own_max_time():
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=["~task.time_budget"])
    budget = pipeline_module.time_budget(cfg)
    assert budget.total_s is None and budget.ahead == QUICK
    assert budget.max_time("train_dynamics") == 150.0 and not budget.shortened("train_dynamics")


@pytest.mark.parametrize(("key", "value", "expected"), [("total", 0.0, "task.time_budget.total"), ("floor", 0.0, "task.time_budget.floor"),
                                                        ("reserve_s", -60.0, "task.time_budget.reserve_s")])
def test_a_budget_that_cannot_work_is_refused_by_its_key(key, value, expected):
    kwargs = {"total_s": 570.0, "reserve_s": 60.0, "floor": 0.25} | {"total_s" if key == "total" else key: value}
    with pytest.raises(ValueError, match=expected):
        TimeBudget(planned=PLANNED, **kwargs)


@pytest.mark.parametrize("late_s", [0.0, 300.0])
def test_the_pipeline_gives_each_trainer_the_budgets_max_time_and_reports_it(tmp_path, monkeypatch, late_s):
    """python run.py (task=pipeline, the quick preset) with every step replaced by a stand-in that
    records the Trainer's max_time: on time each training gets its preset's; after a generation
    ``late_s`` late the trainings share what is left, the report says so and pipeline.json keeps it."""
    clock = Clock()
    monkeypatch.setattr(time_budget_module, "time", SimpleNamespace(perf_counter=clock))
    given: dict[str, float] = {}
    spelled: dict[str, object] = {}  # step -> max_time as its Trainer's config spells it

    def generate(c):
        clock.now += 10.0 + late_s

    def training(stage):
        def train(c):
            step = str(Path(c.paths.output_dir).relative_to(tmp_path))
            spelled[step] = trainer_kwargs(c, c.model[stage])["max_time"]
            given[step] = seconds(spelled[step])
            clock.now += given[step]
            return {"steps": 1, "max_steps": 2, "stopped_by": "max_time", "precision": "32-true"}
        return train

    notes = {}
    monkeypatch.setattr(pipeline_module, "generate", generate)
    monkeypatch.setattr(pipeline_module, "train_dynamics", training("dynamics"))
    monkeypatch.setattr(pipeline_module, "check_identifiability", lambda c: {"skipped": True})
    monkeypatch.setattr(pipeline_module, "train_visual", training("visual"))
    monkeypatch.setattr(pipeline_module, "export_proposals", lambda c: None)
    monkeypatch.setattr(pipeline_module, "train_inference", training("inference"))
    monkeypatch.setattr(pipeline_module, "evaluate", lambda c: {"ablation": c.ablation.name})
    monkeypatch.setattr(pipeline_module, "write_tables", lambda records, out, text: notes.setdefault("text", text))
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=[f"paths.output_dir={tmp_path}", "task.modules_at_once=false",  # one after the other: tests/tasks/test_at_once.py has them side by side
                                           "task.time_budget.total=00:00:10:30"])  # room for the preset's caps and reserve after a 10-s generation
    pipeline_module.pipeline(cfg)
    total, reserve = 630.0, cfg.task.time_budget.reserve_s
    assert list(given) == list(QUICK)
    trained = json.loads((tmp_path / "pipeline.json").read_text())["trained"]
    if late_s == 0.0:
        assert given == QUICK and "task.time_budget" not in notes["text"]
        assert all(isinstance(v, str) for v in spelled.values())  # on time, each keeps the preset's own "DD:HH:MM:SS"
        return
    assert all(given[s] < QUICK[s] for s in QUICK)
    assert clock.now - 1000.0 == pytest.approx(total - reserve)  # the trainings end where the reserve begins
    assert trained["train_visual"]["max_time_s"] == round(given["train_visual"], 1) and trained["train_visual"]["planned_s"] == 75.0
    assert f"shortened its max_time from 75 s to {given['train_visual']:.0f} s" in notes["text"]
