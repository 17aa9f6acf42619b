from __future__ import annotations

import numpy as np
import pytest
import torch

from vgpl.models.dynamics_prior import DynamicsPrior
from vgpl.models.rollout import future_mse, rollout, rollout_runs
from vgpl.nn.rigid import momentum_projection, quaternion_to_matrix, rigid_displacement
from vgpl.sim.envs import make_scene


def inputs(env="rigid_fall", batch=2, steps=60, seed=0):
    scene = make_scene(env, n_steps=steps)
    tr = scene.simulate([scene.sample(np.random.default_rng(seed + s)) for s in range(batch)])
    grouping = torch.nn.functional.one_hot(torch.as_tensor(scene.instance), scene.n_instances).float().expand(batch, -1, -1)
    rigidness = torch.as_tensor(scene.rigid).float().expand(batch, -1)
    return scene, tr, grouping.clone(), rigidness.clone(), scene.planes_at(tr.actions), torch.as_tensor(scene.kinematic)


def model_for(scene, radius=0.08, seed=0, rigid_head="pooled"):
    torch.manual_seed(seed)
    return DynamicsPrior(scene.param_low.tolist(), scene.param_high.tolist(), scene.n_instances, radius=radius, rigid_head=rigid_head)


class Oracle(torch.nn.Module):
    """Returns the true next frame: replaying ground truth through rollout() must give zero error."""

    def __init__(self, truth, history):
        super().__init__()
        self.truth, self.t = truth, 0
        self.hparams = type("H", (), {"history": history})()

    def step(self, window, grouping, rigidness, params, planes, kinematic, driven):
        assert torch.equal(window, self.truth[:, self.t : self.t + 4])  # the window slides correctly
        nxt = self.truth[:, self.t + 4]
        self.t += 1
        return torch.where(kinematic[None, :, None], driven, nxt) if driven is not None else nxt


@pytest.mark.parametrize("env", ["rigid_fall", "mass_rope"])
def test_oracle_replay_gives_zero_error(env):
    scene, tr, g, q, planes, kin = inputs(env, steps=30)
    pred = rollout(Oracle(tr.positions, 4), tr.positions, g, q, tr.params, planes, kin, 20)
    assert all(v == 0.0 for v in future_mse(pred, tr.positions[:, 4:24]).values())


def test_future_mse_is_the_papers_scale():
    a = torch.zeros(1, 20, 5, 3)
    b = torch.full_like(a, 0.01)
    assert future_mse(a, b)["future_mse_x1e4@10"] == pytest.approx(1.0)


@pytest.mark.parametrize("rigid_head", ["pooled", "projected"])
def test_rigid_instances_stay_rigid_over_a_50_step_rollout(rigid_head):
    scene, tr, g, q, planes, kin = inputs("rigid_fall", steps=60)
    model = model_for(scene, rigid_head=rigid_head).eval()
    with torch.no_grad():
        pred = rollout(model, tr.positions[:, :4], g, q, tr.params, planes, kin, 50)
    inst = torch.as_tensor(scene.instance)
    start = tr.positions[:, 3]
    for m in range(3):
        x0 = start[:, inst == m].double()
        d0 = torch.cdist(x0, x0)
        for t in (9, 49):
            xt = pred[:, t, inst == m].double()
            rel = (torch.cdist(xt, xt) - d0).abs() / d0.clamp_min(1e-9)
            rel.diagonal(dim1=1, dim2=2).zero_()
            assert float(rel.max()) < 1e-4
    assert float((pred[:, -1] - start).abs().max()) > 1e-3  # it did move


@pytest.mark.parametrize("rigid_head", ["pooled", "projected"])
def test_predictions_are_equivariant_to_particle_order(rigid_head):
    scene, tr, g, q, planes, kin = inputs("fluid_cube", steps=10)
    model = model_for(scene, rigid_head=rigid_head).eval()
    perm = torch.randperm(scene.n_particles, generator=torch.Generator().manual_seed(0))
    hist = tr.positions[:, :4]
    with torch.no_grad():
        out = model(hist, g, q, tr.params, planes[:, :4], kin)
        out_p = model(hist[:, :, perm], g[:, perm], q, tr.params, planes[:, :4], kin[perm])
    assert torch.allclose(out[:, perm], out_p, atol=1e-5)


@pytest.mark.parametrize(("env", "rigid_head"), [("rigid_fall", "pooled"), ("rigid_fall", "projected"), ("mass_rope", "projected")])
def test_gradients_reach_grouping_rigidness_and_parameters(env, rigid_head):
    scene, tr, g, q, planes, kin = inputs(env, steps=10)
    model = model_for(scene, rigid_head=rigid_head)
    g, q, p = g.clone().requires_grad_(), (q * 0.7).requires_grad_(), tr.params.clone().requires_grad_()
    model(tr.positions[:, :4], g, q, p, planes[:, :4], kin).square().sum().backward()
    for grad in (g.grad, q.grad, p.grad):
        assert grad is not None and float(grad.abs().sum()) > 0 and bool(grad.isfinite().all())


def test_rigid_head_transform():
    pos = torch.tensor([[[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]]])
    g = torch.ones(1, 2, 1)
    quarter = quaternion_to_matrix(torch.tensor([[[np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)]]], dtype=torch.float32))
    disp = rigid_displacement(pos, g, quarter, torch.tensor([[[0.0, 0.0, 1.0]]]))
    assert torch.allclose(pos + disp, torch.tensor([[[0.0, 1.0, 1.0], [0.0, -1.0, 1.0]]]), atol=1e-6)


def test_momentum_projection_recovers_a_rigid_step_and_moves_a_body_pushed_at_one_particle():
    gen = torch.Generator().manual_seed(0)
    pos = torch.randn(2, 64, 3, generator=gen) * 0.1
    g = torch.zeros(2, 64, 2)
    g[:, :32, 0], g[:, 32:, 1] = 1.0, 1.0
    half = 0.025  # a 0.05 rad step about a tilted axis, a fast tumble at 60 frames a second
    axis = torch.nn.functional.normalize(torch.tensor([0.3, 0.5, 0.8]), dim=0)
    rot = quaternion_to_matrix(torch.cat([torch.tensor([np.cos(half)]), np.sin(half) * axis]).float().expand(2, 2, 4))
    step = torch.tensor([0.01, -0.02, 0.03]).expand(2, 2, 3)
    disp = rigid_displacement(pos, g, rot, step)
    rot_fit, step_fit = momentum_projection(pos, g, disp)
    assert torch.allclose(step_fit, step, atol=1e-6)
    assert float((rot_fit - rot).abs().max()) < 5e-4  # first order in the angle: 1% of the 0.05 rad step
    # an impulse on one particle: the body moves by 1/32 of it and turns about the centroid, the other body stays
    push = torch.zeros(2, 64, 3)
    push[:, 0, 0] = 0.032
    rot_fit, step_fit = momentum_projection(pos, g, push)
    assert torch.allclose(step_fit[:, 0], torch.tensor([0.001, 0.0, 0.0]), atol=1e-7)
    assert float(step_fit[:, 1].abs().max()) == 0.0 and torch.allclose(rot_fit[:, 1], torch.eye(3).expand(2, 3, 3))
    assert float((rot_fit[:, 0] - torch.eye(3)).abs().max()) > 1e-4


def test_without_a_rigid_head_the_prior_ignores_rigidness_and_moves_every_particle_freely():
    """rigid_head="none" (the paper's w/o-rigidness prior): Q changes nothing, and no rigid weights exist."""
    scene, tr, g, q, planes, kin = inputs("rigid_fall", steps=10)
    model = model_for(scene, rigid_head="none")
    assert model.rigid_head is None
    rigid, free = (model(tr.positions[:, :4], g, r, tr.params, planes[:, :4], kin) for r in (q, torch.zeros_like(q)))
    torch.testing.assert_close(rigid, free, rtol=0, atol=0)
    constrained = model_for(scene, rigid_head="pooled")
    moved = constrained(tr.positions[:, :4], g, q, tr.params, planes[:, :4], kin) - constrained(tr.positions[:, :4], g, torch.zeros_like(q), tr.params, planes[:, :4], kin)
    assert moved.abs().max() > 1e-3  # where a rigid head exists, Q does move the prediction


def test_history_noise_is_a_random_walk_or_independent_per_frame():
    """random_walk: the first frame exact, the last frame's std the given std; independent: every
    frame perturbed with that std (100k samples: the std to 2%)."""
    from vgpl.models.dynamics_prior import add_history_noise

    torch.manual_seed(0)
    history, movable, std = torch.zeros(25000, 4, 4, 3), torch.tensor([True, True, True, False]), torch.tensor([0.1, 0.2, 0.3])
    walk = add_history_noise(history, std, movable, "random_walk")
    assert walk[:, 0].abs().max() == 0 and walk[:, :, 3].abs().max() == 0
    torch.testing.assert_close(walk[:, -1, :3].reshape(-1, 3).std(0), std, rtol=0.02, atol=0)
    independent = add_history_noise(history, std, movable, "independent")
    assert independent[:, :, 3].abs().max() == 0
    for frame in range(4):
        torch.testing.assert_close(independent[:, frame, :3].reshape(-1, 3).std(0), std, rtol=0.02, atol=0)
    corr = torch.corrcoef(torch.stack([independent[:, 0, 0, 0], independent[:, 3, 0, 0]]))[0, 1]
    assert abs(corr) < 0.03  # frames drawn apart (a walk's frames 1 and 3 correlate at 0.58)
    with pytest.raises(ValueError, match="model.dynamics.net.history_noise"):
        DynamicsPrior([-15.0], [-5.0], 3, radius=0.08, history_noise="pink")


def test_rigid_head_option_is_checked():
    with pytest.raises(ValueError, match="model.dynamics.net.rigid_head"):
        DynamicsPrior([-15.0], [-5.0], 3, radius=0.08, rigid_head="mean")


@pytest.mark.parametrize("env", ["fluid_cube", "mass_rope"])
def test_action_lookahead_shows_the_actuators_next_motion(env):
    """With action_lookahead the prediction of frame H depends on where the container (planes) or
    the pin (kinematic particles) will be at frame H; without it, it cannot."""
    scene, tr, g, q, planes, kin = inputs(env, batch=1, steps=30)
    hist, nxt, window = tr.positions[:, 10:14], tr.positions[:, 14], planes[:, 10:15]
    moved_planes = window.clone()
    moved_planes[:, -1, :, 3] += 0.01  # every plane moves 1 cm further into the scene in the next frame
    moved_next = torch.where(kin[None, :, None], nxt + torch.tensor([0.01, 0.0, 0.0]), nxt)
    for lookahead in (False, True):
        torch.manual_seed(0)
        model = DynamicsPrior(scene.param_low.tolist(), scene.param_high.tolist(), scene.n_instances, radius=0.08, action_lookahead=lookahead).eval()
        with torch.no_grad():
            base = model(hist, g, q, tr.params, window, kin, nxt)
            shifted = model(hist, g, q, tr.params, moved_planes, kin, moved_next)
        changed = float((shifted - base)[:, ~kin].abs().max())
        assert (changed > 0.0) == lookahead, (lookahead, changed)  # exactly unchanged without it


@pytest.mark.parametrize("env", ["fluid_cube", "mass_rope"])
def test_runs_of_different_lengths_roll_together_as_each_alone(env):
    """rollout_runs: runs of 1, 5 and 3 steps from different frames, with their own P and Q, rolled in
    one batch (the container's planes and the pin's frames per run), predict what each run does alone."""
    scene, tr, g, q, planes, kin = inputs(env, batch=2, steps=30)
    h = 4
    torch.manual_seed(0)
    model = DynamicsPrior(scene.param_low.tolist(), scene.param_high.tolist(), scene.n_instances, radius=0.08, history=h,
                          action_lookahead=True).eval()
    runs = [(tr.positions[:, s : s + h + n], g, q * w, tr.params * (1 + 0.1 * w), planes[:, s : s + h + n], n)
            for s, n, w in ((3, 1, 0.0), (0, 5, 1.0), (10, 3, 0.5))]
    with torch.no_grad():
        together = rollout_runs(model, runs, kin)
        for (positions, g_, q_, p_, planes_, n), found in zip(runs, together):
            assert found.shape == (2, n, scene.n_particles, 3)
            torch.testing.assert_close(found, rollout(model, positions, g_, q_, p_, planes_, kin, n), rtol=1e-5, atol=1e-6)
    assert not torch.allclose(together[0][:, 0], together[1][:, 0])  # the runs are not one rollout repeated


def test_a_rollout_short_of_planes_or_driven_frames_is_refused_by_name():
    scene, tr, g, q, planes, kin = inputs("mass_rope", batch=1, steps=10)
    model = DynamicsPrior(scene.param_low.tolist(), scene.param_high.tolist(), scene.n_instances, radius=0.08, history=4).eval()
    with pytest.raises(ValueError, match=r"needs 7 frames of positions \(the kinematic particles' driven frames\).*got 4"):
        rollout(model, tr.positions[:, :4], g, q, tr.params, planes[:, :7], kin, 3)
    with pytest.raises(ValueError, match="needs 7 frames of planes.*got 6"):
        rollout(model, tr.positions[:, :7], g, q, tr.params, planes[:, :6], kin, 3)


def test_action_lookahead_needs_the_predicted_frame():
    scene, tr, g, q, planes, kin = inputs("mass_rope", batch=1, steps=10)
    model = DynamicsPrior(scene.param_low.tolist(), scene.param_high.tolist(), scene.n_instances, radius=0.08, action_lookahead=True)
    with pytest.raises(ValueError, match="planes need 5 frames"):
        model(tr.positions[:, :4], g, q, tr.params, planes[:, :4], kin, tr.positions[:, 4])
    with pytest.raises(ValueError, match="kinematic_next"):
        model(tr.positions[:, :4], g, q, tr.params, planes[:, :5], kin)


def _window_batch(tr, g, q, planes, kin, start: int, frames: int) -> dict:
    b = tr.positions.shape[0]
    return {"positions": tr.positions[:, start : start + frames], "planes": planes[:, start : start + frames], "params": tr.params,
            "grouping": g, "rigidness": q, "kinematic": kin.expand(b, -1)}


def test_rollout_steps_loss_rolls_on_its_own_predictions_and_its_first_step_is_the_one_step_loss():
    scene, tr, g, q, planes, kin = inputs("mass_rope", batch=2, steps=30)  # the pin is kinematic: driven from the data
    make = lambda k: DynamicsPrior(scene.param_low.tolist(), scene.param_high.tolist(), scene.n_instances, radius=0.08,  # noqa: E731
                                   action_lookahead=True, rollout_steps=k)
    torch.manual_seed(0)
    one = make(1)
    three = make(3)
    three.load_state_dict(one.state_dict())
    batch = _window_batch(tr, g, q, planes, kin, 10, 7)
    with torch.no_grad():
        loss1, first1 = one._loss(batch, noise=False)
        loss3, first3 = three._loss(batch, noise=False)
        pred = rollout(three, batch["positions"], g, q, tr.params, batch["planes"], kin, 3)
        teacher = torch.stack([three.step(batch["positions"][:, j : j + 4], g, q, tr.params, batch["planes"][:, j : j + 5], kin,
                                          batch["positions"][:, j + 4]) for j in range(3)], 1)
    truth = batch["positions"][:, 4:7]
    rolled = ((pred - truth) / three.disp_std).abs()[:, :, ~kin].mean()
    forced = ((teacher - truth) / three.disp_std).abs()[:, :, ~kin].mean()
    assert loss1 == first1 and float(first3) == pytest.approx(float(loss1), rel=1e-5)  # k = 1 is exactly the old loss
    assert float(loss3) == pytest.approx(float(rolled), rel=1e-5)
    assert abs(float(loss3) - float(forced)) > 1e-3 * float(forced)  # not teacher-forced: step 2 starts from step 1's prediction
    three._loss(batch, noise=True)[0].backward()
    assert all(p.grad is not None for p in three.parameters() if p.requires_grad)
    with pytest.raises(ValueError, match="rollout_steps=3\\): windows of 5 frames, expected history 4 \\+ 3"):
        three._loss(_window_batch(tr, g, q, planes, kin, 10, 5), noise=False)
    with pytest.raises(ValueError, match="rollout_steps=0"):
        make(0)


def test_noise_free_steps_train_the_last_k_steps_without_history_noise(monkeypatch, caplog):
    """noise_free_steps=2 of max_steps=6: the history noise is drawn at steps 0-3 and not at 4-5;
    a fit that max_epochs stops before the finish says so."""
    import lightning as L
    from torch.utils.data import DataLoader

    import vgpl.models.dynamics_prior as dp

    scene, tr, g, q, planes, kin = inputs("rigid_fall", batch=1, steps=12)
    torch.manual_seed(0)
    model = DynamicsPrior(scene.param_low.tolist(), scene.param_high.tolist(), scene.n_instances, radius=0.08, noise_free_steps=2)
    noisy_steps = []
    real = dp.add_history_noise
    monkeypatch.setattr(dp, "add_history_noise", lambda *a: (noisy_steps.append(model.global_step), real(*a))[1])
    batch = _window_batch(tr, g, q, planes, kin, 2, 5)
    fit = lambda steps: L.Trainer(max_steps=steps, max_epochs=1, logger=False, enable_checkpointing=False, enable_progress_bar=False,  # noqa: E731
                                  enable_model_summary=False, limit_val_batches=0).fit(model, DataLoader([batch] * 8, batch_size=None))
    fit(6)
    assert noisy_steps == [0, 1, 2, 3] and "noise-free finish" not in caplog.text
    fit(20)  # one epoch of 8 batches: max_epochs stops it at step 8, the finish was to begin at step 18
    assert "dynamics: stopped at step 8 of trainer.max_steps=20 before its noise-free finish began (model.dynamics.net.noise_free_steps=2)" in caplog.text
    with pytest.raises(ValueError, match="model.dynamics.net.noise_free_steps=2 needs a finite model.dynamics.trainer.max_steps, or trainer.max_steps"):
        fit(-1)
    with pytest.raises(ValueError, match="noise_free_steps=-1"):
        DynamicsPrior(scene.param_low.tolist(), scene.param_high.tolist(), scene.n_instances, radius=0.08, noise_free_steps=-1)
