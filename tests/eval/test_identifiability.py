from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch

from vgpl.eval.identifiability import oracle_param_sweep, param_gradient_agreement, rigidness_sweep
from vgpl.models.rollout import rollout


class Falling:
    """A stand-in prior: constant-acceleration motion whose acceleration along y is P (or 0 when
    ``blind``, a prior that ignores P)."""

    hparams = SimpleNamespace(history=2)
    disp_std = torch.tensor(0.01)
    low, high = torch.tensor([-15.0]), torch.tensor([-5.0])

    def __init__(self, blind: bool = False, floor: float | None = None) -> None:
        self.blind, self.floor = blind, floor

    def normalise_params(self, p):
        return (p - self.low) / (self.high - self.low) * 2 - 1

    def to_physical(self, u):
        return (u + 1) / 2 * (self.high - self.low) + self.low

    def step(self, window, grouping, rigidness, params, planes, kinematic, driven=None):
        accel = torch.zeros_like(window[:, -1])
        if not self.blind:
            accel[..., 1] = params[:, :1] * (1 / 60) ** 2
        nxt = 2 * window[:, -1] - window[:, -2] + accel
        if self.floor is not None:  # an inelastic floor: what lands stays, whatever P
            nxt = torch.cat([nxt[..., :1], nxt[..., 1:2].clamp(min=self.floor), nxt[..., 2:]], -1)
        return nxt


def _scenes(params: torch.Tensor, n_steps: int = 8, n: int = 5):
    torch.manual_seed(0)
    b = params.shape[0]
    start = torch.rand(b, 2, n, 3)
    start[:, 1] = start[:, 0] + 0.001
    planes, kinematic = torch.zeros(b, 2 + n_steps, 0, 4), torch.zeros(n, dtype=torch.bool)
    truth = torch.cat([start, rollout(Falling(), start, None, None, params, planes, kinematic, n_steps)], 1)
    return truth, planes, kinematic


def test_a_prior_that_depends_on_p_recovers_it_to_within_half_a_grid_step():
    params = torch.tensor([[-15.0], [-12.5], [-7.5], [-5.0], [-11.2]])  # the first four on the 9-point grid
    positions, planes, kinematic = _scenes(params)
    out = oracle_param_sweep(Falling(), positions, None, None, params, planes, kinematic, n_steps=8, grid=9)
    truth = Falling().normalise_params(params)
    assert out["midpoint_param_mae_pct"].item() == pytest.approx((truth.abs() * 50).mean().item())
    # on-grid scenes exact; -11.2 is 0.3 of a 1.25 step from -12.5: the nearest grid value, -11.25
    assert out["oracle_param_mae_pct"].item() == pytest.approx(abs(-11.25 - -11.2) / 10 * 100 / 5, abs=1e-3)
    assert out["grid_param_mae_pct"].item() == pytest.approx(out["oracle_param_mae_pct"].item(), abs=1e-4)  # a perfect prior: the grid's own error
    assert out["loss_curve"].shape == (1, 9) and out["grid"].shape == (9,)


def test_a_prior_blind_to_p_has_a_flat_loss_and_no_oracle():
    params = torch.tensor([[-14.0], [-6.0]])
    positions, planes, kinematic = _scenes(params)
    out = oracle_param_sweep(Falling(blind=True), positions, None, None, params, planes, kinematic, n_steps=8, grid=5)
    curve = out["loss_curve"][0]
    assert torch.allclose(curve, curve[0].expand_as(curve))
    assert out["oracle_param_mae_pct"].item() > out["midpoint_param_mae_pct"].item()  # ties go to the range's low end
    # the 5-point grid is -15, -12.5, -10, -7.5, -5: -14 and -6 are 1 from its nearest values, a tenth of the range
    assert out["grid_param_mae_pct"].item() == pytest.approx(10.0, abs=1e-4)


def test_refining_around_each_scenes_best_resolves_like_a_four_times_finer_grid():
    """9 coarse values (step 0.25 normalised) and 9 more within one step of each scene's best: the
    33-point lattice (step 0.0625), also at the clamped ends of the range."""
    params = torch.tensor([[-10.9], [-5.2], [-14.9]])  # normalised -0.18, 0.96, -0.98
    positions, planes, kinematic = _scenes(params)
    coarse = oracle_param_sweep(Falling(), positions, None, None, params, planes, kinematic, n_steps=8, grid=9)
    fine = oracle_param_sweep(Falling(), positions, None, None, params, planes, kinematic, n_steps=8, grid=9, refine=9)
    lattice = torch.tensor([[-0.1875], [0.9375], [-1.0]])  # the nearest values of the 33-point lattice
    assert Falling().normalise_params(fine["oracle_params"]) == pytest.approx(lattice, abs=1e-5)
    truth = Falling().normalise_params(params)
    expected = ((lattice - truth).abs() * 50).mean().item()  # 0.0075, 0.0225, 0.02 normalised: 0.83%
    assert fine["oracle_param_mae_pct"].item() == pytest.approx(expected, abs=1e-3)
    assert fine["grid_param_mae_pct"].item() == pytest.approx(expected, abs=1e-3)  # a perfect prior: the lattice's own error
    coarse_values = torch.tensor([[-0.25], [1.0], [-1.0]])
    assert coarse["oracle_param_mae_pct"].item() == pytest.approx(((coarse_values - truth).abs() * 50).mean().item(), abs=1e-3)
    # signed, normalised: -0.07, +0.04, -0.02 on the grid; -0.0075, -0.0225, -0.02 refined: both -0.05 / 3, -0.83%
    assert coarse["oracle_param_bias_pct"].item() == pytest.approx(((coarse_values - truth) * 50).mean().item(), abs=1e-3)
    assert fine["oracle_param_bias_pct"].item() == pytest.approx(((lattice - truth) * 50).mean().item(), abs=1e-3)
    assert fine["oracle_param_bias_pct"].item() == pytest.approx(-0.8333, abs=1e-3)
    assert torch.equal(fine["loss_curve"], coarse["loss_curve"])  # the curve stays the coarse grid's


def test_rolling_the_scenes_in_chunks_gives_the_same_sweep():
    params = torch.tensor([[-10.9], [-5.2], [-14.9], [-7.1], [-12.3]])
    positions, planes, kinematic = _scenes(params)
    whole = oracle_param_sweep(Falling(), positions, None, None, params, planes, kinematic, n_steps=8, grid=9, refine=5, chunk=5)
    chunked = oracle_param_sweep(Falling(), positions, None, None, params, planes, kinematic, n_steps=8, grid=9, refine=5, chunk=2)  # 2 + 2 + 1
    for key in ("oracle_params", "oracle_param_mae_pct", "loss_curve"):
        assert torch.allclose(whole[key], chunked[key], atol=1e-6), key
    with pytest.raises(ValueError, match="chunk=0"):
        oracle_param_sweep(Falling(), positions, None, None, params, planes, kinematic, n_steps=8, chunk=0)
    whole = param_gradient_agreement(Falling(), positions, None, None, params, planes, kinematic, n_steps=8, chunk=5)
    chunked = param_gradient_agreement(Falling(), positions, None, None, params, planes, kinematic, n_steps=8, chunk=2)
    assert torch.allclose(whole["median_abs_grad"], chunked["median_abs_grad"]) and torch.equal(whole["counted"], chunked["counted"])
    assert torch.allclose(whole["agreement"], chunked["agreement"], equal_nan=True)


@pytest.mark.parametrize("refine", [1, -2])
def test_a_refinement_of_one_value_is_refused(refine):
    with pytest.raises(ValueError, match=rf"refine={refine} \(task.param_grid_refine or task.identifiability.refine\), expected 0"):
        oracle_param_sweep(Falling(), torch.zeros(1, 3, 2, 3), None, None, torch.tensor([[-10.0]]), torch.zeros(1, 3, 0, 4), torch.zeros(2, dtype=torch.bool), 1, refine=refine)


def test_grid_of_one_value_is_refused():
    with pytest.raises(ValueError, match="grid=1"):
        oracle_param_sweep(Falling(), torch.zeros(1, 3, 2, 3), None, None, torch.tensor([[-10.0]]), torch.zeros(1, 3, 0, 4), torch.zeros(2, dtype=torch.bool), 1, grid=1)


def test_gate_names_only_the_parameters_whose_oracle_is_not_below_the_ratio_times_the_midpoint():
    from vgpl.tasks.identifiability import unidentified

    metrics = {"oracle_param_mae_pct/a": 15.0, "midpoint_param_mae_pct/a": 27.2,   # FluidCube, horizon 15
               "oracle_param_mae_pct/b": 35.9, "midpoint_param_mae_pct/b": 29.1}   # MassRope
    assert unidentified(metrics, ["a", "b"], max_ratio=1.0) == {"b": (35.9, 29.1)}
    assert unidentified(metrics, ["a", "b"], max_ratio=0.5) == {"a": (15.0, 27.2), "b": (35.9, 29.1)}
    assert unidentified(metrics, ["a"], max_ratio=15.0 / 27.2) == {"a": (15.0, 27.2)}  # equal is a failure: strictly below


def test_gradient_in_p_points_to_the_truth_for_every_scene_and_probe_of_a_prior_that_uses_it():
    params = torch.tensor([[-14.0], [-11.0], [-9.0], [-6.0]])
    positions, planes, kinematic = _scenes(params)
    out = param_gradient_agreement(Falling(), positions, None, None, params, planes, kinematic, n_steps=8)
    truth = Falling().normalise_params(params)[:, 0]  # -0.8, -0.2, 0.2, 0.8
    probes = torch.tensor([-0.75, -0.25, 0.25, 0.75])
    assert out["agreement"].shape == (1, 4) and torch.equal(out["probes"], probes)
    assert torch.equal(out["agreement"], torch.ones(1, 4))
    # scenes within 0.1 of a probe are left out: -0.8 of -0.75, -0.2 of -0.25, 0.2 of 0.25, 0.8 of 0.75
    assert out["counted"].tolist() == [[((truth - v).abs() > 0.1).sum().item() for v in probes.tolist()]] == [[3, 3, 3, 3]]
    assert (out["median_abs_grad"] > 0).all()


def test_a_prior_blind_to_p_gives_no_gradient_and_no_agreement():
    params = torch.tensor([[-14.0], [-6.0]])
    positions, planes, kinematic = _scenes(params)
    out = param_gradient_agreement(Falling(blind=True), positions, None, None, params, planes, kinematic, n_steps=8)
    assert torch.equal(out["agreement"], torch.zeros(1, 4)) and torch.equal(out["median_abs_grad"], torch.zeros(1, 4))


def test_windows_after_landing_teach_nothing_while_the_fall_teaches_p():
    """RigidFall in miniature: particles fall onto a floor at y = 0 and stay. A window rolled from the
    fall has the gradient right; one rolled from the rest has none (docs/design.md)."""
    params = torch.tensor([[-14.0], [-11.0], [-6.0]])
    torch.manual_seed(0)
    start = torch.rand(3, 2, 4, 3) * 0.02 + torch.tensor([0.0, 0.05, 0.0])  # 5-7 cm above the floor
    start[:, 1] = start[:, 0]
    planes, kinematic, prior = torch.zeros(3, 30, 0, 4), torch.zeros(4, dtype=torch.bool), Falling(floor=0.0)
    truth = torch.cat([start, rollout(prior, start, None, None, params, planes, kinematic, 28)], 1)  # [3, 30, 4, 3]
    assert (truth[:, 15:, :, 1] == 0).all() and (truth[:, 2, :, 1] > 0).all()  # landed by frame 15, falling at 2
    falling = param_gradient_agreement(prior, truth[:, :10], None, None, params, planes[:, :10], kinematic, n_steps=8)
    landed = param_gradient_agreement(prior, truth[:, 15:25], None, None, params, planes[:, :10], kinematic, n_steps=8)
    assert falling["agreement"].min() == 1.0
    assert landed["agreement"].max() == 0.0 and landed["median_abs_grad"].max() == 0.0


class Damped(Falling):
    """A stand-in prior whose particles keep their velocity when rigid (q = 1) and lose half of it a
    step when not (q = 0), q_i = sum_m G_im Q_m; P plays no part."""

    def step(self, window, grouping, rigidness, params, planes, kinematic, driven=None):
        q = (grouping * rigidness[:, None, :]).sum(-1, keepdim=True)  # [B, N, 1]
        return window[:, -1] + (window[:, -1] - window[:, -2]) * (0.5 + 0.5 * q)


def _two_instances(b: int = 3, n: int = 6, n_steps: int = 6):
    """Scenes of a rigid instance (particles 0-2, 'cube') and a non-rigid one (3-5, 'fluid') moved by ``Damped``."""
    torch.manual_seed(0)
    grouping = torch.nn.functional.one_hot(torch.tensor([0, 0, 0, 1, 1, 1]), 2).float().expand(b, -1, -1)
    rigidness, params = torch.tensor([[1.0, 0.0]]).expand(b, -1), torch.full((b, 1), -10.0)
    start = torch.rand(b, 2, n, 3)
    start[:, 1] = start[:, 0] + 0.01 * torch.randn(b, n, 3)
    planes, kinematic = torch.zeros(b, 2 + n_steps, 0, 4), torch.zeros(n, dtype=torch.bool)
    truth = torch.cat([start, rollout(Damped(), start, grouping, rigidness, params, planes, kinematic, n_steps)], 1)
    return truth, grouping, rigidness, params, planes, kinematic


def test_the_rigidness_sweep_finds_each_types_true_label_where_the_prior_uses_q():
    window = _two_instances()
    out = rigidness_sweep(Damped(), *window, 6, ["cube", "fluid"], chunk=2)
    for name in ("cube", "fluid"):
        assert out[name]["truth_preferred"] == 1.0 and out[name]["oracle_correct"] == 1.0
    assert out["cube"]["l1"].argmin() == 4 and out["fluid"]["l1"].argmin() == 0  # values 0, .25, .5, .75, 1
    assert out["cube"]["l1"][4] == pytest.approx(0.0, abs=1e-5) and (out["cube"]["l1"].diff() < 0).all()


def test_a_prior_blind_to_q_prefers_no_label():
    """A flat loss: no scene prefers the truth (ties are not preferences) and the argmin is the first value, 0."""
    out = rigidness_sweep(Falling(), *_two_instances(), 6, ["cube", "fluid"], values=(0.0, 1.0))
    assert torch.allclose(out["cube"]["l1"], out["cube"]["l1"][0].expand(2))
    assert out["cube"]["truth_preferred"] == 0.0 and out["fluid"]["truth_preferred"] == 0.0
    assert out["cube"]["oracle_correct"] == 0.0 and out["fluid"]["oracle_correct"] == 1.0


@pytest.mark.parametrize("values", [(0.0,), (0.2, 1.0), (0.0, 0.9)])
def test_a_rigidness_sweep_that_misses_either_label_is_refused(values):
    with pytest.raises(ValueError, match="expected at least two, from 0 .non-rigid. to 1 .rigid."):
        rigidness_sweep(Damped(), *_two_instances(), 6, ["cube", "fluid"], values=values)
