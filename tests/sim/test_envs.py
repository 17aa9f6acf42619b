"""The environments match docs/paper.md and reject bad options with one clear error."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.errors import MissingConfigException
from hydra.utils import instantiate

from tests.conftest import REPO
from vgpl.sim.envs import make_scene


@pytest.mark.parametrize(
    "env,n,rigid,low,high,steps,action_dim",
    [
        ("rigid_fall", 192, [True, True, True], -15.0, -5.0, 120, 0),
        ("fluid_cube", 348, [True, False], 1.0, 100.0, 300, 6),
        ("mass_rope", 96, [True, False], 0.25, 1.2, 201, 6),
    ],
)
def test_hydra_env_configs_build_the_papers_scenes(env, n, rigid, low, high, steps, action_dim):
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=[f"env={env}"])
    scene = instantiate(cfg.env.scene)
    assert scene.n_particles == n and scene.rigid.tolist() == rigid
    assert scene.param_low.tolist() == [low] and scene.param_high.tolist() == [high]
    assert scene.n_steps == steps and scene.dt == pytest.approx(1 / 60)
    sample = scene.sample(np.random.default_rng(0))
    assert sample.positions.shape == (n, 3) and sample.actions.shape == (steps, action_dim)
    assert low <= float(sample.params[0]) <= high


def test_particle_counts_per_object():
    assert np.bincount(make_scene("rigid_fall").instance).tolist() == [64, 64, 64]
    assert np.bincount(make_scene("fluid_cube").instance).tolist() == [48, 300]
    assert np.bincount(make_scene("mass_rope").instance).tolist() == [81, 15]  # the rope and its pin


def test_unknown_env_is_named():
    with pytest.raises(ValueError, match="unknown env 'water'.*fluid_cube"):
        make_scene("water")
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"), pytest.raises(MissingConfigException, match="water"):
        compose("config", overrides=["env=water"])


def test_parameter_range_low_above_high_is_named():
    with pytest.raises(ValueError, match="low > high.*gravity"):
        make_scene("rigid_fall", param_low=[-5.0], param_high=[-15.0])
    with pytest.raises(ValueError, match="param_low/param_high.*1 value"):
        make_scene("fluid_cube", param_low=[1.0, 2.0], param_high=[3.0, 4.0])


def test_simulation_is_deterministic_bytes():
    scene = make_scene("fluid_cube", n_steps=20)
    runs = []
    for _ in range(2):
        tr = scene.simulate([scene.sample(np.random.default_rng(s)) for s in (0, 1)])
        runs.append((tr.positions.numpy().tobytes(), scene.renderer().render(tr.positions[:, -1]).numpy().tobytes()))
    assert runs[0] == runs[1]


def test_rollout_does_not_depend_on_its_batch():
    """A rollout's bytes are the same alone or batched with others (shards may be batched differently)."""
    scene = make_scene("rigid_fall", n_steps=40)
    alone = scene.simulate([scene.sample(np.random.default_rng(7))]).positions[0]
    batched = scene.simulate([scene.sample(np.random.default_rng(s)) for s in (3, 7, 9)]).positions[1]
    assert torch.equal(alone, batched)


@pytest.mark.parametrize("env", ["rigid_fall", "fluid_cube", "mass_rope"])
@pytest.mark.parametrize("preset", ["quick", "standard"])
def test_the_timed_presets_draw_the_modules_windows_from_the_first_8_frames(preset, env):
    """RigidFall's gravity shows only while the cubes fall: the inference module's training windows
    start within 8 frames of start_frame, on every env as the quick preset measured them. An
    explicit override still wins."""
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=[f"env={env}", f"experiment={preset}"])
        assert cfg.model.inference.window_span == 8
        cfg = compose("config", overrides=[f"env={env}", f"experiment={preset}", "model.inference.window_span=12"])
        assert cfg.model.inference.window_span == 12


def test_fluid_cubes_cube_sinks_over_its_first_16_frames_then_settles():
    """The cube is dropped onto the fluid and sinks fast over the first 16 frames. Observed from frame 10,
    the inference module read that splash as a thin fluid, so FluidCube is evaluated from frame 20 (``env.start_frame=20``),
    where every scene's cube sinks at under half its fastest speed of frames 0-16."""
    start = 20
    scene = make_scene("fluid_cube", n_steps=start + 4)
    tr = scene.simulate([scene.sample(np.random.default_rng(s)) for s in (0, 1, 2)])
    height = tr.positions[:, :, torch.as_tensor(scene.instance) == 0, 1].mean(-1)  # [B, T] the cube's centroid
    drop = (height[:, :-1] - height[:, 1:]).abs()  # [B, T - 1] per frame
    assert (drop[:, start:] < 0.5 * drop[:, :16].amax(1, keepdim=True)).all()
    assert (height[:, 16] < height[:, 0] - 0.1).all()  # it sank more than 10 cm first


@pytest.mark.parametrize("experiment,stream,videos", [("quick", False, None), ("standard", False, 300), ("paper", True, None)])
def test_the_paper_preset_streams_every_training_video_and_the_timed_ones_hold_theirs(experiment, stream, videos):
    """At the paper's sizes the training videos (~31 GB for RigidFall) are read window by window
    from the shards; the quick preset holds its 64 in memory and the standard one 300 of its 900
    (2 GB), which its 10-minute visual stage sees about three times over."""
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=["env=mass_rope", f"experiment={experiment}"])
    assert cfg.model.visual.stream_video is stream and cfg.model.visual.max_rollouts == videos
    assert cfg.model.densephysnet.stream_video is (experiment == "paper")  # the standard baseline holds its 200 videos


def test_rigid_falls_layout_draws_what_the_authors_generator_draws():
    """Cube j's lattice corner at x, z ~ U(0, 0.1) and y ~ U(b_j, b_j + 0.01), b = 0.09, 0.30, 0.51,
    with no rotation: the cubes start stacked one contact distance apart (the authors' data.py)."""
    scene = make_scene("rigid_fall")
    samples = [scene.sample(np.random.default_rng(s)) for s in range(400)]
    cubes = np.stack([s.positions for s in samples]).reshape(400, 3, 64, 3)
    corner = cubes.min(2) - scene.spacing / 2  # the lattice's corner: half a spacing outside its lowest particles
    for j, b in enumerate((0.09, 0.30, 0.51)):
        for axis, (lo, hi) in enumerate([(0.0, 0.1), (b, b + 0.01), (0.0, 0.1)]):
            drawn = corner[:, j, axis]
            assert lo - 1e-6 <= drawn.min() and drawn.max() <= hi + 1e-6
            assert abs(drawn.mean() - (lo + hi) / 2) < 0.06 * (hi - lo) and drawn.std() == pytest.approx((hi - lo) / np.sqrt(12), rel=0.1)
    np.testing.assert_allclose(cubes - cubes.mean(2, keepdims=True), np.broadcast_to(scene.cube, cubes.shape), atol=1e-6)  # unrotated
    gaps = cubes[:, 1:, :, 1].min(-1) - cubes[:, :-1, :, 1].max(-1)  # between stacked particle layers
    assert gaps.min() >= 0.05 - 1e-6 and gaps.max() <= 0.07 + 1e-6
