from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch

from tests.conftest import simulate
from vgpl.data.trajectories import Rollouts
from vgpl.eval.param_response import engine_from_frame, param_response
from vgpl.nn.normalisation import NormalisationBuffers

DT2 = (1 / 60) ** 2


def _rollouts(scene, traj, velocities: bool = True) -> Rollouts:
    return Rollouts(traj.positions, traj.params, traj.actions, torch.as_tensor(scene.instance), torch.as_tensor(scene.rigid),
                    torch.as_tensor(scene.param_low), torch.as_tensor(scene.param_high), scene.name,
                    velocities=traj.velocities if velocities else None)


def test_the_engine_restarted_from_a_recorded_frame_continues_the_recording_and_a_stiffer_rope_lifts_the_sphere():
    scene, traj = simulate("mass_rope", seeds=(0, 1), n_steps=30)
    rollouts = _rollouts(scene, traj)
    again = engine_from_frame(scene, rollouts, frame=10, n_steps=8, params=traj.params)
    assert again.shape == (2, 8, scene.n_particles, 3)
    assert torch.allclose(again, traj.positions[:, 11:19], atol=1e-6)  # frames 11..18, to float precision
    # the same state with a stiffer rope: more tension at the same stretch pulls the sphere up
    stiffer = engine_from_frame(scene, rollouts, frame=10, n_steps=8, params=traj.params * 1.2)
    sphere = torch.as_tensor(scene.instance == 0)
    rise = (stiffer - again)[:, :, sphere, 1].mean(2)  # [2, 8] centroid height difference
    assert (rise[:, -1] > 1e-3).all() and (rise[:, 1:] >= rise[:, :-1]).all()
    assert scene.n_steps == 30  # the restart works on a copy


@pytest.mark.parametrize("env", ["fluid_cube", "rigid_fall"])
def test_the_restart_is_exact_on_the_other_envs_and_their_parameter_moves_it(env):
    """The fluid's and the rigid bodies' state is their positions and velocities too, so the
    response of FluidCube's viscosity and RigidFall's gravity can be measured the same way."""
    scene, traj = simulate(env, seeds=(0,), n_steps=14)
    rollouts = _rollouts(scene, traj)
    again = engine_from_frame(scene, rollouts, frame=4, n_steps=6, params=traj.params)
    assert torch.allclose(again, traj.positions[:, 5:11], atol=1e-6)
    other = torch.as_tensor(scene.param_high, dtype=traj.params.dtype)[None] if env == "fluid_cube" else traj.params * 1.2
    moved = (engine_from_frame(scene, rollouts, frame=4, n_steps=6, params=other) - again).abs().amax(dim=(0, 2, 3))  # [6]
    assert moved[-1] > 1e-3 and (moved[1:] >= moved[:-1]).all()


def test_a_restart_without_velocities_or_past_the_end_is_refused():
    scene, traj = simulate("mass_rope", seeds=(0,), n_steps=12)
    with pytest.raises(ValueError, match=r"velocities=True"):
        engine_from_frame(scene, _rollouts(scene, traj, velocities=False), 2, 4, traj.params)
    with pytest.raises(ValueError, match="exceed the 12-frame rollouts"):
        engine_from_frame(scene, _rollouts(scene, traj), 8, 4, traj.params)


class ShareOfGravity(NormalisationBuffers, torch.nn.Module):
    """A stand-in prior: constant-acceleration motion under ``share`` of the gravity P along y."""

    def __init__(self, scene, share: float) -> None:
        super().__init__()
        self.share = share
        self.hparams = SimpleNamespace(history=2)
        self.register_normalisation(list(scene.param_low), list(scene.param_high))
        self.disp_std.fill_(1e-3)

    def step(self, window, grouping, rigidness, params, planes, kinematic, kinematic_next=None):
        accel = torch.zeros_like(window[:, -1])
        accel[..., 1] = self.share * params[:, :1] * DT2
        return 2 * window[:, -1] - window[:, -2] + accel


@pytest.fixture(scope="module")
def falling():
    """RigidFall's first 10 frames: the stack falls, its bottom cube reaching the floor from frame 6-7."""
    scene, traj = simulate("rigid_fall", seeds=(0, 1, 2), n_steps=10)
    return scene, _rollouts(scene, traj)


def test_the_response_slope_reads_the_share_of_the_engines_response_a_prior_reproduces(falling):
    scene, rollouts = falling
    full, half, blind = (param_response(ShareOfGravity(scene, s), scene, rollouts, start=0, frames=8, n=3).per_scene() for s in (1.0, 0.5, 0.0))
    # the stand-in integrates the whole frame at once, the engine in substeps: close to 1, not exactly
    assert 0.9 < full["pooled_slope"] < 1.25
    assert (full["cosine"] > 0.999).all()  # both move every particle straight down
    assert half["pooled_slope"] == pytest.approx(0.5 * full["pooled_slope"], rel=1e-3)  # float32 differences
    assert torch.allclose(half["prior_response"], 0.5 * full["prior_response"], rtol=1e-3)
    assert (blind["prior_response"] == 0).all() and blind["pooled_slope"] == 0.0


def test_the_linearised_argmin_finds_the_gravity_a_biased_prior_prefers(falling):
    """A prior with 0.5 of gravity matches the truth at twice the true gravity: the linearised argmin
    moves P by the truth's own magnitude (in physical units), clamped at the range's end."""
    scene, rollouts = falling
    response = param_response(ShareOfGravity(scene, 0.5), scene, rollouts, start=0, frames=8, n=3)
    # frames store the cubes rigidly projected, the engine's state keeps its last floor pass: a restart
    # from a recorded frame after the first floor contact is off by micrometres, not exact
    assert response.restart_error < 2e-5 and response.engine.shape == (3, 8 - 2, scene.n_particles, 3)
    normaliser = ShareOfGravity(scene, 1.0)
    truth = normaliser.normalise_params(rollouts.params)[:, 0]
    wanted = normaliser.normalise_params(2 * rollouts.params)[:, 0] - truth  # exact for a linear prior
    assert torch.allclose(response.per_scene()["linear_error_prior"], wanted, atol=1e-3)
    expected_mae = float(((truth + wanted).clamp(-1, 1) - truth).abs().mean() * 50)
    assert response.summary()["linear_mae_pct_prior_response"] == pytest.approx(expected_mae, rel=1e-4)
    # one cube alone reads the same: the stand-in's error is the same on every particle
    top = torch.as_tensor(scene.instance == 2)
    assert response.summary(top)["linear_mae_pct_prior_response"] == pytest.approx(expected_mae, rel=1e-3)
    assert response.per_scene(top)["engine_response"].lt(response.per_scene()["engine_response"]).all()
