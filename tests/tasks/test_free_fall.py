"""task=free_fall_gravity on real (tiny) RigidFall files: exact on perfect proposals, worse as
their error grows, refused on other envs and on frames the proposals do not cover."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from tests.conftest import REPO
from vgpl.tasks.free_fall import free_fall_gravity
from vgpl.tasks.generate import generate
from vgpl.tasks.train_visual import export_proposals

WINDOW = ["model.inference.window_span=2", "model.inference.observed=10", "model.inference.horizon=1"]  # proposals of 12 frames


def config(tmp: Path, *overrides):
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        return compose("config", overrides=[
            "experiment=none", "env=rigid_fall", "env.scene.n_steps=13", f"data.root={tmp}/data", "data.n_rollouts=6", "data.train_fraction=0.5", "data.shard_size=6",
            "data.render=false", "data.progress=false", f"paths.output_dir={tmp}/run", f"paths.ckpt_dir={tmp}/ckpt", *WINDOW, *overrides])


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("free_fall")
    generate(config(tmp, "task=generate"))
    return tmp


def test_perfect_proposals_give_gravity_exactly_and_noisy_ones_less_so_the_more_noise(data):
    export_proposals(config(data, "task=export_proposals", "task.source=truth"))
    exact = free_fall_gravity(config(data, "task=free_fall_gravity", "task.error_scales=[1.0]"))
    assert exact["fits"][0]["proposal_mse_x1e4"] == 0 and exact["fits"][0]["gravity_mae_pct"] < 1e-2  # float32 files
    assert exact["fits"][0]["calibration"] == pytest.approx([0.0, 1.0], abs=2e-3)  # float32 files, 7 frames: within 0.02% of gravity
    assert exact["midpoint_gravity_mae_pct"] > 5  # the reference a constant scores

    export_proposals(config(data, "task=export_proposals", "task.source=truth", "task.noise_std=0.01"))
    noisy = free_fall_gravity(config(data, "task=free_fall_gravity", "task.error_scales=[1.0,0.5,0.0]"))
    fits = noisy["fits"]
    assert [f["error_scale"] for f in fits] == [1.0, 0.5, 0.0]
    assert fits[0]["proposal_mse_x1e4"] == pytest.approx(1.0, rel=0.05)  # 1 cm per coordinate: 1e-4 m^2
    assert fits[1]["proposal_mse_x1e4"] == pytest.approx(fits[0]["proposal_mse_x1e4"] / 4)
    assert fits[0]["gravity_mae_pct"] > fits[1]["gravity_mae_pct"] > fits[2]["gravity_mae_pct"] == pytest.approx(0, abs=1e-2)
    written = json.loads((data / "run/metrics.json").read_text())
    assert written["fits"] == fits and written["frames"] == 7 and written["n_test"] == 3 and written["n_train"] == 3
    assert "| 0.5 |" in (data / "run/free_fall_gravity.md").read_text()


def test_other_envs_and_uncovered_frames_are_refused_by_name(data):
    with pytest.raises(ValueError, match="env=rigid_fall only \\(got env=fluid_cube\\)"):
        free_fall_gravity(config(data, "task=free_fall_gravity", "env=fluid_cube"))
    with pytest.raises(ValueError, match="task.frames=13: expected 3 to 12"):
        free_fall_gravity(config(data, "task=free_fall_gravity", "task.frames=13"))
