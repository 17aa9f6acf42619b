"""Replaying FleX rollouts in vgpl's engine and the numbers that compare two worlds."""

from __future__ import annotations

import numpy as np
import pytest

from vgpl.data.flex_rollouts import FlexRollout
from vgpl.eval.flex_fidelity import mass_rope_outcomes, position_mse_x1e4, replay, rigid_fall_outcomes
from vgpl.sim.envs import make_scene


def _as_flex(scene, positions: np.ndarray, gravity: float, name: str) -> FlexRollout:
    return FlexRollout("rigid_fall", name, positions, None, np.array([gravity], np.float32), scene.instance, scene.rigid, np.zeros(12))


def test_replaying_the_engines_own_rollouts_gives_them_back_and_jitter_parts_them():
    scene = make_scene("rigid_fall", n_steps=30)
    samples = [scene.sample(np.random.default_rng(s)) for s in (0, 1)]
    own = scene.simulate(samples).positions.numpy()
    rollouts = [_as_flex(scene, own[k], float(samples[k].params[0]), str(k)) for k in range(2)]
    again = replay(scene, rollouts)
    np.testing.assert_array_equal(again, own)  # same start, same gravity, same frame count
    assert scene.n_steps == 30  # the scene's own length is restored
    assert position_mse_x1e4(again, own).max() == 0.0
    jittered = position_mse_x1e4(replay(scene, rollouts, jitter=1e-3), own)
    assert 0.0 < jittered[0] < 0.03  # about (1 mm)^2 x 1e4 = 0.01 at the start


def test_replay_refuses_rollouts_of_another_particle_layout():
    scene = make_scene("rigid_fall", levels=[0.09, 0.30])  # two cubes
    rollout = _as_flex(make_scene("rigid_fall"), np.zeros((5, 192, 3), np.float32), -9.8, "7")
    with pytest.raises(ValueError, match=r"FleX rollout 7: 192 particles in instances \[64, 64, 64\], env 'rigid_fall' has 128"):
        replay(scene, [rollout])


def test_position_mse_is_per_coordinate_times_1e4():
    a = np.zeros((2, 3, 4, 3))
    b = a.copy()
    b[:, 1, :, 0] = 0.01  # 1 cm along x in frame 1: (0.01^2) / 3 coordinates x 1e4
    np.testing.assert_allclose(position_mse_x1e4(a, b), [0.0, 1.0 / 3, 0.0])


def test_outcomes_of_a_fall_a_landing_and_a_slide():
    """Two cubes of 8 particles: the bottom one falls freely, lands at frame 6 and slides 3 cm along
    x; the top one ends on it (not on the floor) in rollout 0 and on the floor in rollout 1."""
    dt, g, t = 0.1, -10.0, np.arange(12)
    instance = np.repeat([0, 1], 8)
    corner = np.stack(np.meshgrid(*[[0.0, 0.05]] * 3, indexing="ij"), -1).reshape(-1, 3)
    height = np.where(t < 6, 1.0 + 0.5 * g * (t * dt) ** 2, 1.0 + 0.5 * g * (5 * dt) ** 2)  # stops after frame 5
    height = height - height[-1] + 0.01  # rests with its lowest particle at 1 cm
    slide = np.clip(t - 6, 0, 3) * 0.01
    bottom = corner[None] + np.stack([slide, height, 0 * t], -1)[:, None]
    positions = np.zeros((2, 12, 16, 3))
    positions[:, :, :8] = bottom
    positions[0, :, 8:] = corner + [0.0, 0.2, 0.0]
    positions[1, :, 8:] = corner + [0.3, 0.02, 0.0]
    out = rigid_fall_outcomes(positions, instance, np.array([g, g]), dt)
    assert out["cubes_on_floor"] == 3 and out["cubes"] == 4
    assert out["resting_height"] == pytest.approx([0.01, 0.01])
    assert out["lowest"] == pytest.approx(0.01)
    assert out["bottom_slide"] == pytest.approx([0.03, 0.03])
    assert out["first_contact"] == [5, 5]  # frame 5's acceleration (frames 4, 5, 6) is no longer g


def test_mass_rope_replay_drives_the_recorded_pin_and_starts_with_the_kick():
    """MassRope's own rollouts, read back as FleX rollouts (no velocities recorded, as the authors'
    MassRope files): the replay drives the pin along the recorded path and starts the mass at the
    scene's kick, so it gives the rollouts back exactly."""
    scene = make_scene("mass_rope", n_steps=25)
    samples = [scene.sample(np.random.default_rng(s)) for s in (0, 1)]
    own = scene.simulate(samples).positions.numpy()
    rollouts = [FlexRollout("mass_rope", str(k), own[k], None, samples[k].params, scene.instance, scene.rigid, np.zeros(6), pin=own[k, :, -1])
                for k in range(2)]
    np.testing.assert_allclose(replay(scene, rollouts), own, atol=1e-5)


def test_mass_rope_outcomes_of_a_stretched_rope_and_a_turned_mass():
    """A mass of 4 particles and a rope of 2 segments from its last particle to the pin (rest 0.2 m):
    from frame 1 on the rope is stretched by 50%, the mass is turned 90 degrees about y and the whole
    scene is moved 0.3 m along x."""
    mass = np.array([[0.1, 0.0, 0.0], [-0.1, 0.0, 0.0], [0.0, 0.0, 0.1], [0.0, 0.05, 0.0]])
    turned = mass @ np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]).T  # 90 degrees about y
    positions = np.zeros((1, 3, 6, 3))
    for t in range(3):
        body, segment, shift = (mass, 0.1, 0.0) if t == 0 else (turned, 0.15, 0.3)
        positions[0, t, :4] = body
        positions[0, t, 4] = body[-1] + [0.0, segment, 0.0]
        positions[0, t, 5] = body[-1] + [0.0, 2 * segment, 0.0]
        positions[0, t, :, 0] += shift
    out = mass_rope_outcomes(positions, n_mass=4, rest_length=0.2)
    assert out["mass_turn"] == pytest.approx([90.0, 90.0], abs=1e-3)
    assert out["mass_drop"] == pytest.approx([0.0, 0.0], abs=1e-9)
    assert out["rope_stretch"] == pytest.approx([1 / 3, 1 / 3], abs=1e-4) and out["rope_stretch_peak"] == pytest.approx(0.5, abs=1e-4)
    assert out["pin_travel"] == pytest.approx([np.sqrt(0.06)] * 2, abs=1e-4)  # RMS of 0, 0.3, 0.3
