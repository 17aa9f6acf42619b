"""The aligned per-edge computation is the exact-width one: losses and gradients of both learned
modules that pass messages, at the paper's width 150, to 1e-5 in float32."""

from __future__ import annotations

import pytest
import torch

import vgpl.nn.propagation as propagation
from tests.conftest import simulate
from tests.models.inference_options import inference_module
from vgpl.models.dynamics_prior import DynamicsPrior


def _grads(module, loss):
    loss.backward()
    return {name: w.grad.clone() for name, w in module.named_parameters() if w.grad is not None}


def _both(monkeypatch, compute):
    """compute() at ALIGNMENT 8 (the default: 152 columns at width 150) and at 1 (150)."""
    out = compute()
    monkeypatch.setattr(propagation, "ALIGNMENT", 1)
    exact = compute()
    return out, exact


def test_width_150_is_computed_152_wide_with_zero_columns():
    assert propagation.aligned(150) == 152 and propagation.aligned(48) == 48
    enc = propagation.EdgeEncoder(7, 5, 150)
    code = enc(torch.rand(10, 7), torch.rand(4, 5), torch.tensor([[0, 1, 2, 3], [1, 2, 3, 4]]), torch.nn.Linear(150, 150))
    assert code.shape == (4, 152) and not code[:, 150:].any()


def test_the_dynamics_priors_step_and_gradients_are_the_exact_widths(monkeypatch):
    scene, traj = simulate("rigid_fall", seeds=(0, 1), n_steps=8)
    kinematic = torch.as_tensor(scene.kinematic)
    grouping = torch.nn.functional.one_hot(torch.as_tensor(scene.instance).long(), scene.n_instances).float()[None].expand(2, -1, -1)

    def compute():
        torch.manual_seed(0)
        prior = DynamicsPrior(scene.param_low.tolist(), scene.param_high.tolist(), scene.n_instances, 0.08, width=150)
        history = traj.positions[:, :4].clone().requires_grad_(True)
        out = prior(history, grouping, torch.full((2, scene.n_instances), 0.7), traj.params, torch.zeros(2, 4, 0, 4), kinematic)
        loss = (out**2).mean()
        grads = _grads(prior, loss)
        return out.detach(), grads, history.grad

    (out, grads, hist), (out1, grads1, hist1) = _both(monkeypatch, compute)
    torch.testing.assert_close(out, out1, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(hist, hist1, rtol=1e-5, atol=1e-5)
    assert grads.keys() == grads1.keys() and len(grads) > 10
    for name in grads:
        torch.testing.assert_close(grads[name], grads1[name], rtol=1e-5, atol=1e-5, msg=name)


def test_the_inference_modules_training_loss_and_gradients_are_the_exact_widths(monkeypatch):
    """The whole training computation: both encoders, the rollouts of both starts through the prior, the tail."""
    scene, traj = simulate("rigid_fall", seeds=(0, 1), n_steps=16)
    n, m = scene.n_particles, scene.n_instances
    grouping = torch.nn.functional.one_hot(torch.as_tensor(scene.instance).long(), m).float()
    batch = {"proposals": traj.positions[:, :8] + 0.003 * torch.randn(2, 8, n, 3, generator=torch.Generator().manual_seed(0)),
             "logits": (8.0 * grouping)[None, None].expand(2, 8, -1, -1), "positions": traj.positions[:, :11], "planes": torch.zeros(2, 11, 0, 4),
             "params": traj.params, "kinematic": torch.zeros(2, n, dtype=torch.bool), "rigid": torch.ones(2, m), "grouping": grouping[None].expand(2, -1, -1)}

    def compute():
        torch.manual_seed(0)
        prior = DynamicsPrior(scene.param_low.tolist(), scene.param_high.tolist(), m, 0.08, width=150)
        module = inference_module(scene.param_low.tolist(), scene.param_high.tolist(), n, m, 0.08, width=150, horizon=3,
                                  training_scheme="joint", trajectory_start="both", tail_horizon=3, one_step_windows=0, refined_steps=None, truth_steps=None)
        module.set_stats(prior)
        module.attach_dynamics(prior)
        loss = module._losses(batch)["loss"]
        return loss.detach(), _grads(module, loss)

    (loss, grads), (loss1, grads1) = _both(monkeypatch, compute)
    assert float(loss) == pytest.approx(float(loss1), rel=1e-5)
    assert grads.keys() == grads1.keys()
    for name in grads:
        torch.testing.assert_close(grads[name], grads1[name], rtol=1e-5, atol=1e-5, msg=name)


def test_the_receivers_sum_is_torch_geometrics_sum_aggregation_in_value_and_gradient(monkeypatch):
    """Propagator sums its messages with index_add (a cheap backward); PyG's own "sum"
    aggregation gives the same node effects and the same gradients, to 1e-5 in float32."""
    from torch_geometric.nn import MessagePassing

    torch.manual_seed(0)
    step = propagation.Propagator(32)
    n, e = 60, 700
    edge_index = torch.stack([torch.randint(0, n, (e,)), torch.randint(0, n, (e,)).sort().values])
    effect, code, term = torch.randn(n, 32, requires_grad=True), torch.randn(n, 32), torch.randn(e, 32, requires_grad=True)

    def compute():
        out = step(effect, code, term, edge_index)
        grads = torch.autograd.grad((out * torch.linspace(-1, 1, 32)).sum(), [effect, term, *step.parameters()])
        return out.detach(), grads

    ours, ours_grads = compute()
    monkeypatch.setattr(propagation.Propagator, "aggregate", MessagePassing.aggregate)
    library, library_grads = compute()
    assert ours.abs().max() > 0.1  # messages reach the receivers
    torch.testing.assert_close(ours, library, rtol=1e-5, atol=1e-5)
    for a, b in zip(ours_grads, library_grads):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-5)
