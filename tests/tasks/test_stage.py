"""How a stage's training ended is recorded, and the pipeline's report flags the stages that
trainer.max_time cut short (their numbers depend on the machine's speed)."""

from __future__ import annotations

import shutil
import time

import lightning as L
import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf
from omegaconf.errors import InterpolationKeyError
from torch.utils.data import DataLoader, TensorDataset

from tests.conftest import REPO
from vgpl.hardware import fast_precision
from vgpl.models.step_learning_rate import annealed_fraction
from vgpl.tasks import TASKS, check_resolvable, run_task
from vgpl.tasks.pipeline import time_budget, training_summary
from vgpl.tasks.stage import (
    LastValidation,
    SpentTimeWarning,
    checkpointing,
    max_time_key,
    snapshots,
    spent_time_warning,
    stopping,
    trainer_kwargs,
    validate_final,
)
from vgpl.tasks.stage import fit as stage_fit
from vgpl.tasks.stage_folder import StageFolderError
from vgpl.tasks.time_budget import seconds


class SlowRegression(L.LightningModule):
    """A linear fit whose every step sleeps ``delay`` seconds (a stand-in for a slow machine)."""

    def __init__(self, delay: float) -> None:
        super().__init__()
        self.delay = delay
        self.layer = torch.nn.Linear(2, 1)

    def training_step(self, batch, batch_idx):
        time.sleep(self.delay)
        x, y = batch
        return torch.nn.functional.mse_loss(self.layer(x), y)

    def configure_optimizers(self):
        return torch.optim.SGD(self.parameters(), lr=0.1)


def fit(delay: float, ckpt_path: str | None = None, **limits) -> L.Trainer:
    data = DataLoader(TensorDataset(torch.randn(64, 2), torch.randn(64, 1)), batch_size=4)  # 16 steps an epoch
    trainer = L.Trainer(logger=False, enable_checkpointing=False, enable_progress_bar=False, enable_model_summary=False, **limits)
    trainer.fit(SlowRegression(delay), data, ckpt_path=ckpt_path)
    return trainer


def test_a_fit_that_reaches_max_steps_says_so():
    assert stopping(fit(0.0, max_steps=5)) == {"steps": 5, "max_steps": 5, "stopped_by": "max_steps", "precision": "32-true"}


def test_a_fit_cut_by_max_time_says_how_many_steps_it_ran():
    ended = stopping(fit(0.25, max_steps=1000, max_time={"seconds": 1}))
    assert ended["stopped_by"] == "max_time" and ended["max_steps"] == 1000
    assert 2 <= ended["steps"] <= 6  # about 1 s of 0.25 s steps


def test_a_fit_that_runs_out_of_epochs_says_so():
    assert stopping(fit(0.0, max_epochs=1)) == {"steps": 16, "max_steps": -1, "stopped_by": "max_epochs", "precision": "32-true"}


def test_the_report_lists_every_training_and_flags_the_time_capped_one():
    trained = {"train_dynamics": {"steps": 1200, "max_steps": 1200, "stopped_by": "max_steps"},
               "train_inference/full": {"steps": 97, "max_steps": 170, "stopped_by": "max_time"}}
    text = training_summary(trained, {"train_dynamics": 203.4, "train_inference/full": 120.0})
    assert "- train_dynamics: 1200 of 1200 steps, 203 s\n" in text
    assert "- train_inference/full: 97 of 170 steps, 120 s **stopped by trainer.max_time**" in text


@pytest.mark.parametrize("max_epochs,reaches_max_steps", [(1, False), (-1, True)])
def test_a_fit_resumed_after_a_time_stop_reaches_max_steps_only_without_an_epoch_cap(tmp_path, max_epochs, reaches_max_steps):
    """Lightning counts the epoch a max_time stop cut as done: the resumed fit starts the next one.
    With an epoch cap it can end at once; budgeted in steps (max_epochs=-1) it goes on to max_steps."""
    cut = fit(0.05, max_steps=40, max_epochs=max_epochs, max_time={"seconds": 0.5})
    assert stopping(cut)["stopped_by"] == "max_time" and cut.global_step < 16  # inside the first epoch
    cut.save_checkpoint(tmp_path / "last.ckpt")
    resumed = stopping(fit(0.0, str(tmp_path / "last.ckpt"), max_steps=40, max_epochs=max_epochs))
    assert (resumed["steps"] == 40) is reaches_max_steps
    assert resumed["stopped_by"] == ("max_steps" if reaches_max_steps else "max_epochs")


@pytest.mark.parametrize(("preset", "stage"), [("quick", "dynamics"), ("quick", "visual"), ("quick", "inference"),
                                             ("standard", "dynamics"), ("standard", "visual"), ("standard", "inference"), ("standard", "densephysnet")])
def test_the_timed_presets_stop_every_stage_by_steps_or_minutes_never_by_epochs(preset, stage):
    """Each stage the preset's pipeline trains (the standard one trains DensePhysNet too) has a finite
    max_steps and a max_time; max_epochs is out of reach (an epoch cap would end a resumed run
    early: test above)."""
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=[f"experiment={preset}"])
    kwargs = trainer_kwargs(cfg, cfg.model[stage])
    assert kwargs["max_steps"] > 0 and kwargs["max_time"] and kwargs["max_epochs"] == 1000


def test_snapshots_keep_a_checkpoint_every_n_steps_named_by_its_step(tmp_path):
    data = DataLoader(TensorDataset(torch.randn(64, 2), torch.randn(64, 1)), batch_size=4)  # 16 steps an epoch
    trainer = L.Trainer(logger=False, callbacks=[snapshots(tmp_path, 5)], enable_progress_bar=False, enable_model_summary=False, max_steps=22)
    trainer.fit(SlowRegression(0.0), data)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["step10.ckpt", "step15.ckpt", "step20.ckpt", "step5.ckpt"]
    for n in (5, 10, 15, 20):
        assert torch.load(tmp_path / f"step{n}.ckpt", weights_only=False)["global_step"] == n
    with pytest.raises(ValueError, match="snapshot_every_n_steps=0"):
        snapshots(tmp_path, 0)


class ValidatedRegression(SlowRegression):
    def validation_step(self, batch, batch_idx):
        x, y = batch
        self.log("val/loss", torch.nn.functional.mse_loss(self.layer(x), y))


def test_a_copied_stage_folder_resumes_into_its_own_last_ckpt_without_versioned_copies(tmp_path):
    """A stage folder copied and resumed to train on: Lightning's version counter would write
    last-v1.ckpt and best-v1.ckpt and leave last.ckpt at the copy's step, so ``ckpt_path=last``
    after a kill would restart from there."""
    data = DataLoader(TensorDataset(torch.randn(64, 2), torch.randn(64, 1)), batch_size=4)  # 16 steps an epoch

    def fit_into(folder, max_steps, ckpt_path=None):
        trainer = L.Trainer(logger=False, callbacks=checkpointing(folder, "val/loss"), enable_progress_bar=False,
                            enable_model_summary=False, max_steps=max_steps, max_epochs=-1, val_check_interval=8)
        trainer.fit(ValidatedRegression(0.0), data, data, ckpt_path=ckpt_path)

    fit_into(tmp_path / "original", 16)
    shutil.copytree(tmp_path / "original", tmp_path / "copy")
    fit_into(tmp_path / "copy", 48, str(tmp_path / "copy" / "last.ckpt"))  # no save after fit, as a kill leaves it
    assert sorted(p.name for p in (tmp_path / "copy").iterdir()) == ["best.ckpt", "last.ckpt"]
    assert torch.load(tmp_path / "copy" / "last.ckpt", weights_only=False)["global_step"] > 16  # saved by the resumed run
    assert torch.load(tmp_path / "original" / "last.ckpt", weights_only=False)["global_step"] == 16


class FrozenRegression(ValidatedRegression):
    def configure_optimizers(self):
        return torch.optim.SGD(self.parameters(), lr=0.0)  # the validation loss never improves after the first


def test_last_ckpt_follows_every_validation_even_when_the_monitor_stops_improving(tmp_path):
    """Lightning's save_last writes last.ckpt only beside a new best: a kill after the monitor
    stopped improving would have resumed from the last improvement."""
    data = DataLoader(TensorDataset(torch.randn(64, 2), torch.randn(64, 1)), batch_size=4)
    trainer = L.Trainer(logger=False, callbacks=checkpointing(tmp_path, "val/loss"), enable_progress_bar=False,
                        enable_model_summary=False, max_steps=40, max_epochs=-1, val_check_interval=8)
    trainer.fit(FrozenRegression(0.0), data, data)  # no save after fit, as a kill leaves it
    assert torch.load(tmp_path / "best.ckpt", weights_only=False)["global_step"] == 8
    assert torch.load(tmp_path / "last.ckpt", weights_only=False)["global_step"] >= 32


class CountedRegression(ValidatedRegression):
    def __init__(self, delay: float) -> None:
        super().__init__(delay)
        self.validations = 0

    def on_validation_epoch_end(self) -> None:
        self.validations += 1


@pytest.mark.parametrize("max_steps,validations", [(20, 3), (16, 2)])
def test_the_reported_validation_describes_the_final_weights(max_steps, validations):
    """A fit stopped at step 1,822 would report step 1,500's validation, so a fit that ends between validations is validated once more; one that ends on a validation is not."""
    torch.manual_seed(0)
    x, y = torch.randn(64, 2), torch.randn(64, 1)
    data = DataLoader(TensorDataset(x, y), batch_size=64)
    train = DataLoader(TensorDataset(x, y), batch_size=4)  # 16 steps an epoch
    model = CountedRegression(0.0)
    seen = LastValidation()
    trainer = L.Trainer(logger=False, callbacks=[seen], enable_checkpointing=False, enable_progress_bar=False,
                        enable_model_summary=False, max_steps=max_steps, max_epochs=-1, val_check_interval=8, num_sanity_val_steps=0)
    trainer.fit(model, train, data)
    datamodule = L.LightningDataModule.from_datasets(val_dataset=TensorDataset(x, y), batch_size=64)
    validate_final(trainer, model, datamodule)
    assert seen.step == trainer.global_step == max_steps  # the latest validation is of the final step
    assert model.validations == validations
    final = torch.nn.functional.mse_loss(model.layer(x), y)
    assert float(trainer.callback_metrics["val/loss"]) == pytest.approx(float(final), rel=1e-6)


@pytest.mark.parametrize("env", ["rigid_fall", "fluid_cube", "mass_rope"])
def test_the_standard_preset_trains_the_quick_presets_networks_on_more_videos_for_longer(env):
    """experiment=standard is the quick recipe at a larger scale: every network key, rate, scheme
    and precision is the quick preset's, so the choices measured per CPU minute there carry over;
    the data, the step and time caps and the weights' averaging are what grow."""
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        quick = compose("config", overrides=[f"env={env}", "experiment=quick"])
        standard = compose("config", overrides=[f"env={env}", "experiment=standard"])
    for stage in ("dynamics", "visual", "inference", "densephysnet"):
        nets = [OmegaConf.to_container(cfg.model[stage].net) for cfg in (quick, standard)]
        for net in nets:  # a step count: the prior's noise-free finish is the last quarter of each preset's steps
            net.pop("noise_free_steps", None)
        assert nets[0] == nets[1], stage
        assert trainer_kwargs(standard, standard.model[stage])["max_steps"] > trainer_kwargs(quick, quick.model[stage])["max_steps"], stage
    for stage in ("dynamics", "visual", "inference"):  # the precisions measured per CPU minute
        assert trainer_kwargs(standard, standard.model[stage])["precision"] == trainer_kwargs(quick, quick.model[stage])["precision"], stage
    test_videos = round(standard.data.n_rollouts * (1 - standard.data.train_fraction))
    assert test_videos == standard.eval.max_rollouts == 100 and standard.task.baseline and not quick.task.baseline
    assert (standard.model.dynamics.ema.decay, standard.model.inference.ema.decay) == (0.999, 0.995)


def test_the_standard_preset_plans_its_trainings_inside_its_one_hour_clock():
    """The trainings' planned minutes (the two modules side by side count once each, as they hold
    the machine together), the time held back for export and the evaluations, and five minutes for
    generating RigidFall's 1,000 videos fit in the hour; the budget shortens the trainings when
    generation runs late (FluidCube's longer videos: 500 of them)."""
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=["env=rigid_fall", "experiment=standard"])
        fluid = compose("config", overrides=["env=fluid_cube", "experiment=standard"])
    planned = time_budget(cfg).ahead
    assert planned == {"train_dynamics": 720, "train_visual": 600, "train_inference/full": 600,
                       "train_inference/no_rigidness": 600, "train_baseline": 300}
    assert cfg.task.modules_at_once and seconds(cfg.task.time_budget.total) == 3600
    assert sum(planned.values()) + cfg.task.time_budget.reserve_s + 5 * 60 <= 3600
    fluid_videos = (fluid.data.n_rollouts, round(fluid.data.n_rollouts * (1 - fluid.data.train_fraction)))
    assert fluid_videos == (500, fluid.eval.max_rollouts) and fluid.env.start_frame == 20  # observed past the cube's splash


def test_the_standard_prior_ends_without_history_noise_on_its_clock():
    """The last 7,500 of the 30,000 steps train without the history noise; the 12-min clock stops a
    2-core CPU before 30,000 steps, so the finish runs on the clock: from minute 9 to the end, and
    by step on a machine fast enough to reach 30,000. The quick prior finishes its last quarter too."""
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=["env=mass_rope", "experiment=standard"])
        quick = compose("config", overrides=["env=rigid_fall", "experiment=quick"]).model.dynamics
    k, trainer = cfg.model.dynamics.net.noise_free_steps, trainer_kwargs(cfg, cfg.model.dynamics)
    max_steps, budget_s = trainer["max_steps"], seconds(trainer["max_time"])
    assert (k, max_steps, budget_s) == (7500, 30000, 720)
    begins_s = (1 - k / max_steps) * budget_s
    assert begins_s == pytest.approx(540.0)
    assert annealed_fraction(10000, max_steps, k, elapsed_s=begins_s - 1, budget_s=budget_s) == 1.0  # still noisy
    assert annealed_fraction(10000, max_steps, k, elapsed_s=begins_s + 1, budget_s=budget_s) < 1.0  # noise-free
    assert annealed_fraction(22501, max_steps, k, elapsed_s=60.0, budget_s=budget_s) < 1.0  # by step on a fast machine
    assert (quick.net.noise_free_steps, quick.trainer.max_steps) == (750, 3000)


@pytest.mark.parametrize("preset", ["quick", "standard"])
def test_the_timed_presets_train_the_prior_in_fp32_on_every_cpu_and_the_other_stages_where_bf16_is_native(preset):
    """At width 48 the prior's step is faster in fp32 even where the CPU has bf16 units
    (docs/benchmarks.md), so the presets fix its precision, and the baseline's; the visual prior and
    the modules keep the CPU's choice."""
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=["env=rigid_fall", f"experiment={preset}"])
    precision = {stage: trainer_kwargs(cfg, cfg.model[stage])["precision"] for stage in ("dynamics", "visual", "inference")}
    assert precision == {"dynamics": "32-true", "visual": fast_precision("bf16-mixed"), "inference": fast_precision("bf16-mixed")}
    if preset == "standard":  # the baseline it trains keeps the fp32 it was measured in
        assert trainer_kwargs(cfg, cfg.model.densephysnet)["precision"] == "32-true"


REFERENCE_STEPS = [22561, 9521, 2598, 330]  # conf/per_env/standard_steps/rigid_fall.yaml


def test_the_standard_preset_in_steps_runs_the_reference_machines_steps_without_a_clock():
    """experiment=standard_steps: each stage of RigidFall's standard preset runs the steps it
    reached in its minutes on the reference machine (docs/results.md), with the noise-free
    finish over the same share as on the clock, on the standard preset's dataset and with no run
    clock; on an env without reference steps reading a step budget fails, naming the key it lacks."""
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        steps = compose("config", overrides=["env=rigid_fall", "experiment=standard_steps"])
        clock = compose("config", overrides=["env=rigid_fall", "experiment=standard"])
        other = compose("config", overrides=["env=mass_rope", "experiment=standard_steps"])
    given = {s: trainer_kwargs(steps, steps.model[s]) for s in ("dynamics", "visual", "inference", "densephysnet")}
    assert all(t["max_time"] is None for t in given.values()) and steps.task.time_budget.total is None
    assert [given[s]["max_steps"] for s in ("dynamics", "visual", "inference", "densephysnet")] == REFERENCE_STEPS
    noise_free = steps.model.dynamics.net.noise_free_steps / given["dynamics"]["max_steps"]
    assert noise_free == pytest.approx(clock.model.dynamics.net.noise_free_steps / clock.model.dynamics.trainer.max_steps, abs=1e-3)
    assert steps.paths.data_dir == clock.paths.data_dir and steps.paths.ckpt_dir != clock.paths.ckpt_dir
    module = [{**OmegaConf.to_container(c.model.inference), "trainer": None} for c in (steps, clock)]
    assert module[0] == module[1]  # the rest is the standard preset
    with pytest.raises(InterpolationKeyError, match="reference_steps.dynamics"):
        other.model.dynamics.trainer.max_steps  # noqa: B018


def test_a_task_whose_config_cannot_resolve_fails_before_it_reads_or_writes_anything(tmp_path):
    """run_task resolves the whole composed config first: standard_steps on MassRope (no reference steps)
    fails for a single stage as for the pipeline, naming the key, before data are generated or loaded
    (a stage's trainer is otherwise resolved only once built, after its data were read).
    Every task resolves on the standard preset, and the pipeline on every other env x preset."""
    root = tmp_path / "root"
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        for task in ("generate", "train_dynamics", "pipeline"):
            cfg = compose("config", overrides=["env=mass_rope", "experiment=standard_steps", f"task={task}",
                                               f"paths.root_dir={root}", f"paths.output_dir={root}/out"])
            with pytest.raises(ValueError, match=rf"task={task}: .*'model\.dynamics\.trainer\.max_steps'.*"
                                                 r"reference_steps\.dynamics.*nothing was read or written"):
                run_task(cfg)
            assert not root.exists()
        tasks = sorted(p.stem for p in (REPO / "conf" / "task").glob("*.yaml"))
        assert set(tasks) == set(TASKS)
        runs = [("rigid_fall", "standard", task) for task in tasks] + [
            (env, preset, "pipeline") for env in ("rigid_fall", "mass_rope", "fluid_cube")
            for preset in ("quick", "standard", "paper") + (("standard_steps",) if env == "rigid_fall" else ())]
        for env, preset, task in runs:
            check_resolvable(compose("config", overrides=[f"env={env}", f"experiment={preset}", f"task={task}",
                                                          f"paths.output_dir={tmp_path}/out"]))


def test_a_resume_whose_checkpoint_already_spent_max_time_is_warned_with_the_total_to_pass(tmp_path, caplog):
    """Lightning's Timer restores the time already spent, so max_time bounds the total over resumed
    runs: a resume under a max_time the checkpoint has spent takes no step. The warning
    reads the restored Timer at fit start."""
    cut = fit(0.25, max_steps=1000, max_epochs=-1, max_time={"seconds": 1})
    cut.save_checkpoint(tmp_path / "cut.ckpt")
    with caplog.at_level("WARNING", logger="vgpl.tasks.stage"):
        again = fit(0.25, str(tmp_path / "cut.ckpt"), max_steps=1000, max_epochs=-1, max_time={"seconds": 1},
                    callbacks=[SpentTimeWarning("model.inference.trainer.max_time")])
    assert again.global_step == cut.global_step  # the fact the warning is about
    [message] = [r.getMessage() for r in caplog.records if r.name == "vgpl.tasks.stage"]
    assert message.startswith((f"{tmp_path / 'cut.ckpt'}: holds 00:00:00:01 ", f"{tmp_path / 'cut.ckpt'}: holds 00:00:00:02 "))  # 1-2 s spent
    assert "model.inference.trainer.max_time=00:00:00:01" in message and "model.inference.trainer.max_time=00:01:00:0" in message
    caplog.clear()
    with caplog.at_level("WARNING", logger="vgpl.tasks.stage"):
        longer = fit(0.0, str(tmp_path / "cut.ckpt"), max_steps=cut.global_step + 2, max_epochs=-1, max_time={"minutes": 1},
                     callbacks=[SpentTimeWarning()])  # a minute in total: 58 s left to train
        fit(0.0, max_steps=2, max_time={"seconds": 1}, callbacks=[SpentTimeWarning()])  # not a resume
        fit(0.0, str(tmp_path / "cut.ckpt"), max_steps=cut.global_step + 2, max_epochs=-1,
            callbacks=[SpentTimeWarning()])  # no clock, no limit
        fit(0.0, max_steps=3).save_checkpoint(tmp_path / "unclocked.ckpt")  # max_time=null: Lightning adds no Timer
        fit(0.0, str(tmp_path / "unclocked.ckpt"), max_steps=5, max_time={"seconds": 1}, callbacks=[SpentTimeWarning()])
    assert longer.global_step == cut.global_step + 2
    assert not [r for r in caplog.records if r.name == "vgpl.tasks.stage"]


def test_the_spent_time_warning_is_for_a_resumed_checkpoint_at_or_past_its_limit():
    message = spent_time_warning("last.ckpt", 3600.0, 3600.0, "model.dynamics.trainer.max_time")
    assert message.startswith("last.ckpt: holds 00:01:00:00 of training already, at or past model.dynamics.trainer.max_time=00:01:00:00")
    assert message.endswith("pass model.dynamics.trainer.max_time=00:02:00:00 (the time spent plus the new)")
    assert spent_time_warning("last.ckpt", 3599.0, 3600.0) is None  # a second left
    assert spent_time_warning(None, 3600.0, 3600.0) is None  # a fresh fit
    assert spent_time_warning("last.ckpt", 3600.0, None) is None  # no max_time


def test_the_stages_fit_warns_before_resuming_past_its_max_time_and_names_the_option(tmp_path, caplog):
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=[f"paths.ckpt_dir={tmp_path}", f"paths.output_dir={tmp_path}", "model.dynamics.trainer.max_time=00:00:00:01",
                                           "model.dynamics.trainer.max_steps=1000", "trainer.max_epochs=-1",
                                           "model.dynamics.trainer.val_check_interval=2", "trainer.limit_val_batches=1"])
    data = L.LightningDataModule.from_datasets(TensorDataset(torch.randn(64, 2), torch.randn(64, 1)),
                                               TensorDataset(torch.randn(8, 2), torch.randn(8, 1)), batch_size=4)
    first, _ = stage_fit(cfg, "toy", cfg.model.dynamics, ValidatedRegression(0.25), data)
    assert stopping(first)["stopped_by"] == "max_time"
    timers = [c for c in torch.load(tmp_path / "toy" / "last.ckpt", weights_only=False)["callbacks"].values() if "time_elapsed" in c]
    assert timers[0]["time_elapsed"]["train"] >= 1.0  # the time the resume below restores
    assert max_time_key(cfg, cfg.model.dynamics) == "model.dynamics.trainer.max_time"  # the stage's own, not the group's
    cfg.ckpt_path = "last"
    with caplog.at_level("WARNING"):
        resumed, _ = stage_fit(cfg, "toy", cfg.model.dynamics, ValidatedRegression(0.25), data)
    assert resumed.global_step == first.global_step
    assert f"{tmp_path / 'toy' / 'last.ckpt'}: holds" in caplog.text and "pass model.dynamics.trainer.max_time=00:01:00:0" in caplog.text


class DivergingRegression(ValidatedRegression):
    """Its loss turns NaN at ``at_step`` (as a shard with NaN or a diverging rate makes it)."""

    def __init__(self, at_step: int) -> None:
        super().__init__(0.0)
        self.at_step = at_step

    def training_step(self, batch, batch_idx):
        loss = super().training_step(batch, batch_idx)
        return loss * float("nan") if self.global_step >= self.at_step else loss


def test_a_training_whose_loss_turns_nan_stops_with_the_stage_and_step_and_saves_no_nan_weights(tmp_path):
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=[f"paths.ckpt_dir={tmp_path}", f"paths.output_dir={tmp_path}", "model.dynamics.trainer.max_time=null",
                                           "model.dynamics.trainer.max_steps=40", "trainer.max_epochs=-1", "trainer.enable_progress_bar=false",
                                           "model.dynamics.trainer.val_check_interval=4", "trainer.limit_val_batches=1"])
    data = L.LightningDataModule.from_datasets(TensorDataset(torch.randn(64, 2), torch.randn(64, 1)),
                                               TensorDataset(torch.randn(8, 2), torch.randn(8, 1)), batch_size=4)
    with pytest.raises(FloatingPointError, match=r"toy: the training loss is nan at step 10; stopped before any checkpoint"):
        stage_fit(cfg, "toy", cfg.model.dynamics, DivergingRegression(at_step=9), data)
    saved = torch.load(tmp_path / "toy" / "last.ckpt", weights_only=False)
    assert saved["global_step"] == 8 and all(bool(torch.isfinite(w).all()) for w in saved["state_dict"].values())


def _toy_stage(tmp_path, *overrides):
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=[f"paths.ckpt_dir={tmp_path}", f"paths.output_dir={tmp_path}", "model.dynamics.trainer.max_time=null",
                                           "model.dynamics.trainer.max_steps=8", "trainer.max_epochs=-1", "trainer.enable_progress_bar=false",
                                           "model.dynamics.trainer.val_check_interval=4", "trainer.limit_val_batches=1", *overrides])
    data = L.LightningDataModule.from_datasets(TensorDataset(torch.randn(64, 2), torch.randn(64, 1)),
                                               TensorDataset(torch.randn(8, 2), torch.randn(8, 1)), batch_size=4)
    return cfg, data


def test_a_trained_stage_folder_is_refused_unless_resumed_or_overwritten(tmp_path):
    """A new training over a trained last.ckpt (here with max_steps=0, which would have saved step 0
    over it) is refused naming the folder and both ways out, and leaves the checkpoint as it was;
    ckpt_path=last resumes it and overwrite=true trains it again from scratch."""
    cfg, data = _toy_stage(tmp_path)
    stage_fit(cfg, "toy", cfg.model.dynamics, ValidatedRegression(0.0), data)
    trained = (tmp_path / "toy" / "last.ckpt").read_bytes()
    again, _ = _toy_stage(tmp_path, "model.dynamics.trainer.max_steps=0")
    with pytest.raises(StageFolderError, match=rf"{tmp_path / 'toy'}: holds a trained checkpoint \(last.ckpt\).*ckpt_path=last.*overwrite=true"):
        stage_fit(again, "toy", again.model.dynamics, ValidatedRegression(0.0), data)
    assert (tmp_path / "toy" / "last.ckpt").read_bytes() == trained
    resumed, _ = _toy_stage(tmp_path, "ckpt_path=last", "model.dynamics.trainer.max_steps=12")
    assert stage_fit(resumed, "toy", resumed.model.dynamics, ValidatedRegression(0.0), data)[0].global_step == 12
    fresh, _ = _toy_stage(tmp_path, "overwrite=true", "model.dynamics.trainer.max_steps=4")
    assert stage_fit(fresh, "toy", fresh.model.dynamics, ValidatedRegression(0.0), data)[0].global_step == 4
    assert torch.load(tmp_path / "toy" / "last.ckpt", weights_only=False)["global_step"] == 4
    maybe, _ = _toy_stage(tmp_path, "overwrite=maybe")
    with pytest.raises(ValueError, match="overwrite='maybe': expected true or false"):
        stage_fit(maybe, "toy", maybe.model.dynamics, ValidatedRegression(0.0), data)


class LockCheck(ValidatedRegression):
    """Tries, at its first step, to start a second training of the same stage folder."""

    def __init__(self, cfg, data) -> None:
        super().__init__(0.0)
        self.cfg, self.data, self.refusal = cfg, data, None

    def on_train_start(self) -> None:
        try:
            stage_fit(self.cfg, "toy", self.cfg.model.dynamics, ValidatedRegression(0.0), self.data)
        except StageFolderError as error:
            self.refusal = str(error)


def test_a_second_training_of_a_stage_folder_is_refused_while_the_first_runs(tmp_path):
    """Two trainings of one folder would leave one's config.yaml beside the other's last.ckpt and mix
    their TensorBoard events: the second is refused (by an OS lock, released when the first ends)."""
    cfg, data = _toy_stage(tmp_path)
    other, _ = _toy_stage(tmp_path, "overwrite=true")
    model = LockCheck(other, data)
    stage_fit(cfg, "toy", cfg.model.dynamics, model, data)
    assert model.refusal is not None and "another training is writing this stage folder" in model.refusal and str(tmp_path / "toy") in model.refusal
    assert torch.load(tmp_path / "toy" / "last.ckpt", weights_only=False)["global_step"] == 8  # the first run's, alone
    stage_fit(other, "toy", other.model.dynamics, ValidatedRegression(0.0), data)  # the lock is free again once the first ended


@pytest.mark.parametrize(("override", "message"), [("model.dynamics.trainer.max_steps=3.5", r"model\.dynamics\.trainer\.max_steps=3\.5: expected an integer"),
                                                   ("trainer.max_epochs=two", r"trainer\.max_epochs='two': expected an integer")])
def test_a_step_count_that_is_not_a_whole_number_is_refused_before_the_folder_is_written(tmp_path, override, message):
    """Lightning ran trainer.max_steps=3.5 as 4 steps without a word."""
    cfg, data = _toy_stage(tmp_path, override)
    with pytest.raises(ValueError, match=message):
        stage_fit(cfg, "toy", cfg.model.dynamics, ValidatedRegression(0.0), data)
    assert not (tmp_path / "toy").exists()
