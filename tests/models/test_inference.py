from __future__ import annotations

import inspect
import math

import lightning
import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from tests.conftest import REPO
from tests.models.inference_options import inference_module
from vgpl.data.proposals import propose_videos
from vgpl.data.vertical_symmetry import about_vertical
from vgpl.graph import own_radius_graph
from vgpl.models.dynamics_prior import DynamicsPrior
from vgpl.models.inference import Encoder, InferenceModule, built
from vgpl.models.loss_runs import LossRuns
from vgpl.models.rollout import rollout_runs as inference_rollout_runs
from vgpl.models.visual_prior import VisualPrior
from vgpl.nn.rigid_start import rigid_start
from vgpl.tasks.pipeline import ABLATIONS, ablation_config


def test_capped_radius_graph_keeps_the_nearest_neighbours():
    torch.manual_seed(0)
    pos = torch.rand(40, 3) * 0.1  # dense: everyone within r of everyone
    full = own_radius_graph(pos, 1.0)
    capped = own_radius_graph(pos, 1.0, max_neighbors=5)
    assert full.shape[1] == 40 * 39 and capped.shape[1] == 40 * 5
    dist = torch.cdist(pos, pos) + torch.eye(40) * 9
    for i in range(40):
        sources = capped[0, capped[1] == i]
        assert set(sources.tolist()) == set(dist[i].topk(5, largest=False).indices.tolist())


JOINT = {"training_scheme": "joint", "one_step_windows": 0, "refined_steps": None, "truth_steps": None}  # every trajectory from the refined start


def _modules(n=24, m=2, **kwargs):
    """A tiny prior and module; the module trains by the joint scheme through the window and horizon unless ``kwargs`` say otherwise."""
    dyn = DynamicsPrior([-15.0], [-5.0], m, radius=0.3, width=16)
    inf = inference_module([-15.0], [-5.0], n, m, radius=0.3, width=16, horizon=2, **{**JOINT, **kwargs})
    inf.set_stats(dyn)
    inf.attach_dynamics(dyn)
    return dyn, inf


def _batch(b=2, t=8, n=24, labels=False):
    """A window batch; ``labels`` adds the true rigidness and grouping the paper's scheme rolls with."""
    batch = {
        "proposals": torch.rand(b, t, n, 3), "logits": torch.randn(b, t, n, 2), "positions": torch.rand(b, t + 2, n, 3),
        "planes": torch.zeros(b, t + 2, 0, 4), "params": torch.tensor([[-9.0], [-12.0]]), "kinematic": torch.zeros(b, n, dtype=torch.bool),
    }
    if labels:
        batch |= {"rigid": torch.tensor([[1.0, 0.0]] * b), "grouping": torch.nn.functional.one_hot(torch.arange(n) % 2, 2).float().expand(b, n, 2)}
    return batch


def test_training_loss_reaches_rigidness_and_parameters_only_through_the_frozen_prior():
    torch.manual_seed(0)
    dyn, inf = _modules()
    inf._losses(_batch())["loss"].backward()
    assert inf.rigid_head.lins[-1].weight.grad.abs().sum() > 0
    assert inf.param_head.lins[-1].weight.grad.abs().sum() > 0
    assert all(p.grad is None for p in dyn.parameters())  # frozen
    assert not any(k.startswith("dynamics") for k in inf.state_dict())  # not part of the checkpoint


@pytest.mark.parametrize("start", ["refined", "truth", "both"])
def test_which_trajectory_trains_the_refinement_and_which_the_parameters(start):
    torch.manual_seed(0)
    _, inf = _modules(trajectory_start=start)
    losses = inf._losses(_batch())
    heads = [inf.refine_head.lins[-1].weight, inf.param_head.lins[-1].weight]
    grads = {k: torch.autograd.grad(losses[k], heads, allow_unused=True, retain_graph=True) for k in ("rollout", "rollout_from_truth") if k in losses}
    assert set(grads) == {"refined": {"rollout"}, "truth": {"rollout_from_truth"}, "both": {"rollout", "rollout_from_truth"}}[start]
    none = lambda grad: grad is None or not grad.any()  # noqa: E731  ("both" rolls the two starts as one batch: exact zeros)
    if "rollout_from_truth" in grads:  # from the true frames: P, never dX
        refine_grad, param_grad = grads["rollout_from_truth"]
        assert none(refine_grad) and param_grad.abs().sum() > 0
    if "rollout" in grads:  # from the refined frames: dX, and P unless the true start trains it
        refine_grad, param_grad = grads["rollout"]
        assert refine_grad.abs().sum() > 0
        assert none(param_grad) if start == "both" else (param_grad.abs().sum() > 0)
    expected = losses["refine"] + sum(losses[k] for k in grads)
    torch.testing.assert_close(losses["loss"], expected)


def test_both_starts_rolled_as_one_batch_give_each_start_alone():
    """trajectory_start="both" rolls the refined and the true start as one batch of 2B scenes; each
    loss is what a rollout of its start alone gives (a reference computed here with rollout())."""
    from vgpl.models.rollout import rollout

    torch.manual_seed(0)
    dyn, inf = _modules(trajectory_start="both")
    batch = _batch()
    losses = inf._losses(batch)
    with torch.no_grad():
        out = inf.infer(batch["proposals"], batch["logits"], batch["kinematic"][0])
    truth, t, h = batch["positions"], batch["proposals"].shape[1], dyn.hparams.history
    target = truth[:, h:]
    for name, start in (("rollout", out["positions"][:, :h]), ("rollout_from_truth", truth[:, :h])):
        alone = rollout(dyn, torch.cat([start, target], 1), out["grouping"], out["rigidness"], out["params"], batch["planes"],
                        batch["kinematic"][0], t - h + inf.hparams.horizon)
        torch.testing.assert_close(losses[name].detach(), ((alone - target) / dyn.disp_std).abs().mean(), rtol=1e-5, atol=1e-7)


def test_the_paper_scheme_rolls_each_network_with_the_true_values_of_the_others_outputs():
    """training_scheme="paper": the refinement-and-rigidness network's rollout (refined start) takes
    the true P and reaches neither the parameter head nor its encoder; the parameter network's
    rollout starts at the true frames with the true G and Q and reaches only P's pathway. Each loss
    equals a rollout computed here with those inputs."""
    from vgpl.models.rollout import rollout

    torch.manual_seed(0)
    dyn, inf = _modules(training_scheme="paper")
    batch = _batch(labels=True)
    losses = inf._losses(batch)
    param_pathway = inf.param_pathway()
    rest = [w for w in inf.parameters() if all(w is not v for v in param_pathway)]
    grad = lambda loss, ws: [g for g in torch.autograd.grad(loss, ws, allow_unused=True, retain_graph=True) if g is not None]  # noqa: E731
    assert all(not g.any() for g in grad(losses["rollout"], param_pathway))
    assert sum(g.abs().sum() for g in grad(losses["rollout"], [inf.refine_head.lins[-1].weight, inf.rigid_head.lins[-1].weight])) > 0
    assert all(not g.any() for g in grad(losses["rollout_from_truth"], rest))
    assert grad(losses["rollout_from_truth"], [inf.param_head.lins[-1].weight])[0].abs().sum() > 0
    with torch.no_grad():
        out = inf.infer(batch["proposals"], batch["logits"], batch["kinematic"][0])
    truth, t, h = batch["positions"], batch["proposals"].shape[1], dyn.hparams.history
    target, n_roll = truth[:, h:], t - h + inf.hparams.horizon
    inputs = {"rollout": (out["positions"][:, :h], out["grouping"], out["rigidness"], batch["params"]),
              "rollout_from_truth": (truth[:, :h], batch["grouping"], batch["rigid"], out["params"])}
    for name, (start, g, q, p) in inputs.items():
        alone = rollout(dyn, torch.cat([start, target], 1), g, q, p, batch["planes"], batch["kinematic"][0], n_roll)
        torch.testing.assert_close(losses[name].detach(), ((alone - target) / dyn.disp_std).abs().mean(), rtol=1e-5, atol=1e-7)


def test_the_authors_code_lengths_one_step_from_each_refined_history_and_two_steps_from_the_truth():
    """refined_steps=0, truth_steps=2, one_step_windows=None (the authors' code): dX and Q learn from
    one step off every refined history of the window, fed the true P; P from a 2-step rollout off the
    true frames. Each loss equals the prior's prediction computed here with those inputs."""
    from vgpl.models.rollout import rollout

    torch.manual_seed(0)
    dyn, inf = _modules(training_scheme="paper", one_step_windows=None, refined_steps=0, truth_steps=2)
    batch = _batch(labels=True)
    losses = inf._losses(batch)
    assert "rollout" not in losses and {"one_step", "rollout_from_truth"} <= set(losses)
    torch.testing.assert_close(losses["loss"], losses["one_step"] + losses["rollout_from_truth"] + losses["refine"])
    with torch.no_grad():
        out = inf.infer(batch["proposals"], batch["logits"], batch["kinematic"][0])
    truth, t, h, kin = batch["positions"], batch["proposals"].shape[1], dyn.hparams.history, batch["kinematic"][0]
    two = rollout(dyn, torch.cat([truth[:, :h], truth[:, h : h + 2]], 1), batch["grouping"], batch["rigid"], out["params"], batch["planes"], kin, 2)
    torch.testing.assert_close(losses["rollout_from_truth"].detach(), ((two - truth[:, h : h + 2]) / dyn.disp_std).abs().mean(), rtol=1e-5, atol=1e-7)
    one = torch.stack([dyn.step(out["positions"][:, s : s + h], out["grouping"], out["rigidness"], batch["params"], batch["planes"][:, s : s + h + 1],
                                kin, truth[:, s + h]) for s in range(t - h)])
    target = torch.stack([truth[:, s + h] for s in range(t - h)])
    torch.testing.assert_close(losses["one_step"].detach(), ((one - target) / dyn.disp_std).abs().mean(), rtol=1e-5, atol=1e-7)


def test_a_run_longer_than_the_window_or_negative_is_refused():
    with pytest.raises(ValueError, match="truth_steps=-1"):
        _modules(truth_steps=-1)
    _, inf = _modules(trajectory_start="both", truth_steps=99)
    with pytest.raises(ValueError, match="truth_steps=99: a window holds 6 frames"):
        inf._losses(_batch())


def test_the_paper_scheme_needs_the_papers_two_networks():
    with pytest.raises(ValueError, match="inference_scheme=paper .* needs encoder.separate_param_net=true"):
        _modules(training_scheme="paper", separate_param_net=False)


def test_the_tail_loss_rolls_from_the_last_refined_frames_where_the_evaluation_starts():
    """tail_horizon=k: an L1 of k frames rolled from the last h refined frames past the window."""
    from vgpl.models.rollout import rollout

    torch.manual_seed(0)
    dyn, inf = _modules(tail_horizon=2)
    batch = _batch()
    losses = inf._losses(batch)
    with torch.no_grad():
        out = inf.infer(batch["proposals"], batch["logits"], batch["kinematic"][0])
    truth, t, h = batch["positions"], batch["proposals"].shape[1], dyn.hparams.history
    alone = rollout(dyn, torch.cat([out["positions"][:, t - h :], truth[:, t:]], 1), out["grouping"], out["rigidness"], out["params"],
                    batch["planes"][:, t - h :], batch["kinematic"][0], 2)
    torch.testing.assert_close(losses["tail"].detach(), ((alone - truth[:, t:]) / dyn.disp_std).abs().mean(), rtol=1e-5, atol=1e-7)
    torch.testing.assert_close(losses["loss"], losses["rollout"] + losses["tail"] + losses["refine"])
    heads = lambda module: [module.refine_head.lins[-1].weight, module.rigid_head.lins[-1].weight, module.param_head.lins[-1].weight]  # noqa: E731
    grads = torch.autograd.grad(losses["tail"], heads(inf))
    assert all(g.abs().sum() > 0 for g in grads)  # by default it trains the refinement, Q and P
    detached = InferenceModule(**{**inf.hparams, "training": {**inf.hparams.training, "tail_detach_rigidness": True}})  # the same weights and prior
    detached.load_state_dict(inf.state_dict())
    detached.attach_dynamics(dyn)
    d_losses = detached._losses(batch)
    torch.testing.assert_close(d_losses["tail"], losses["tail"])  # the same loss ...
    grads = torch.autograd.grad(d_losses["tail"], heads(detached), allow_unused=True)
    assert [g is not None and bool(g.any()) for g in grads] == [True, False, True]  # ... with no gradient on Q
    assert "tail" not in _modules()[1]._losses(batch)  # off by default (the paper)
    with pytest.raises(ValueError, match="tail_horizon=3, expected 0 \\(off\\) to model.inference.horizon=2"):
        _modules(tail_horizon=3)


def test_in_the_paper_scheme_the_tail_rolls_with_the_true_parameters():
    """training_scheme="paper" with tail_horizon=k: the tail rolls the last h refined frames with the
    true P and the module's Q, so its gradient never reaches P; with tail_detach_rigidness (the quick
    preset's) it reaches dX alone, and Q and P learn as in the paper."""
    from vgpl.models.rollout import rollout

    torch.manual_seed(0)
    paper = {"training_scheme": "paper", "one_step_windows": None, "refined_steps": 0, "truth_steps": 2, "tail_horizon": 2}
    dyn, inf = _modules(**paper)
    q_grad, *p_grads = torch.autograd.grad(inf._losses(_batch(labels=True))["tail"], [inf.rigid_head.lins[-1].weight, *inf.param_pathway()],
                                           allow_unused=True)
    assert q_grad.abs().sum() > 0 and all(g is None or not g.any() for g in p_grads)  # Q, not P
    dyn, inf = _modules(**paper, tail_detach_rigidness=True)
    batch = _batch(labels=True)
    losses = inf._losses(batch)
    with torch.no_grad():
        out = inf.infer(batch["proposals"], batch["logits"], batch["kinematic"][0])
    truth, t, h = batch["positions"], batch["proposals"].shape[1], dyn.hparams.history
    alone = rollout(dyn, torch.cat([out["positions"][:, t - h :], truth[:, t:]], 1), out["grouping"], out["rigidness"], batch["params"],
                    batch["planes"][:, t - h :], batch["kinematic"][0], 2)
    torch.testing.assert_close(losses["tail"].detach(), ((alone - truth[:, t:]) / dyn.disp_std).abs().mean(), rtol=1e-5, atol=1e-7)
    grads = torch.autograd.grad(losses["tail"], [inf.refine_head.lins[-1].weight, *inf.rigid_head.parameters(), *inf.param_pathway()], allow_unused=True)
    assert grads[0].abs().sum() > 0 and all(g is None or not g.any() for g in grads[1:])


@pytest.mark.parametrize("start", ["refined", "both"])
def test_bernoulli_rigidness_learns_from_the_rollout_error_expected_over_each_label(start):
    """rigidness_estimator=bernoulli: the prior sees the label Q > 0.5; Q's loss is
    mean Q L1(rigid) + (1 - Q) L1(free) over scenes and instances, each L1 rolled here with that
    instance's label set by hand (on the trajectory that trains P), and Q learns from it alone."""
    from vgpl.models.rollout import rollout

    torch.manual_seed(0)
    dyn, inf = _modules(trajectory_start=start, rigidness_estimator="bernoulli")
    batch = _batch()
    losses = inf._losses(batch)
    with torch.no_grad():
        out = inf.infer(batch["proposals"], batch["logits"], batch["kinematic"][0])
    prob, labels = out["rigidness_prob"], out["rigidness"]
    assert torch.equal(labels, (prob > 0.5).float()) and not torch.equal(labels, prob)
    truth, t, h = batch["positions"], batch["proposals"].shape[1], dyn.hparams.history
    first = truth[:, :h] if start == "both" else out["positions"][:, :h]  # the start P learns from
    target, n_roll = truth[:, h:], t - h + inf.hparams.horizon

    def error(q):  # [B] the trajectory L1 per scene with labels q [B, M]
        future = rollout(dyn, torch.cat([first, target], 1), out["grouping"], q, out["params"], batch["planes"], batch["kinematic"][0], n_roll)
        return ((future - target) / dyn.disp_std).abs().mean((1, 2, 3))

    expected = torch.zeros(())
    with torch.no_grad():
        for m in range(labels.shape[1]):
            rigid, free = labels.clone(), labels.clone()
            rigid[:, m], free[:, m] = 1.0, 0.0
            expected = expected + (prob[:, m] * error(rigid) + (1 - prob[:, m]) * error(free)).mean() / labels.shape[1]
    torch.testing.assert_close(losses["rigidness"].detach(), expected, rtol=1e-5, atol=1e-7)
    others = losses["loss"] - losses["rigidness"]
    q_weights = list(inf.rigid_head.parameters())
    assert all(g is None or not g.any() for g in torch.autograd.grad(others, q_weights, allow_unused=True, retain_graph=True))
    assert sum(g.abs().sum() for g in torch.autograd.grad(losses["rigidness"], q_weights)) > 0
    blend = _modules(trajectory_start=start)[1]._losses(batch)  # the paper's: Q is the prior's input, no separate loss
    assert "rigidness" not in blend
    with pytest.raises(ValueError, match="rigidness_estimator=bernoulli flips labels on one rollout length"):
        _modules(rigidness_estimator="bernoulli", truth_steps=2)


def test_unknown_trajectory_start_is_refused():
    with pytest.raises(ValueError, match=r"model.inference.net.scheme.start='proposals', expected 'refined'"):
        _modules(trajectory_start="proposals")


def test_rigidness_reading_is_logged_per_object_type_and_never_trained_on():
    """rigid_correct/<type>: the mean probability Q gives the true label, per type, as task=evaluate's rigidness_prob."""
    torch.manual_seed(0)
    _, inf = _modules(m=3, instance_types=["cube", "fluid", "cube"])
    batch = {**_batch(), "logits": torch.randn(2, 8, 24, 3)}
    without = inf._losses(batch)
    assert not any(k.startswith("rigid_correct") for k in without)
    torch.manual_seed(0)
    _, inf = _modules(m=3, instance_types=["cube", "fluid", "cube"])
    rigid = torch.tensor([[True, False, True]] * 2)
    losses = inf._losses({**batch, "rigid": rigid})
    torch.testing.assert_close(losses["loss"], without["loss"])  # logged only
    with torch.no_grad():
        q = inf.infer(batch["proposals"], batch["logits"], batch["kinematic"][0])["rigidness"]  # [2, 3]
    torch.testing.assert_close(losses["rigid_correct/cube"], q[:, [0, 2]].mean())
    torch.testing.assert_close(losses["rigid_correct/fluid"], 1 - q[:, 1].mean())
    ablated = _modules(m=3, rigidness=False)[1]._losses({**batch, "rigid": rigid})  # Q is zero: nothing to read
    assert not any(k.startswith("rigid_correct") for k in ablated)
    with pytest.raises(ValueError, match="instance_types=.*expected n_instances=3"):
        _modules(m=3, instance_types=["cube", "fluid"])


def test_ablation_switches():
    torch.manual_seed(0)
    _, inf = _modules()
    prop, logits = torch.rand(3, 6, 24, 3), torch.randn(3, 6, 24, 2)
    kin = torch.zeros(24, dtype=torch.bool)
    full = inf.infer(prop, logits, kin)
    assert not torch.equal(full["positions"], prop) and (full["rigidness"] > 0).all()
    assert torch.equal(inf.infer(prop, logits, kin, refinement=False)["positions"], prop)
    assert (inf.infer(prop, logits, kin, rigidness=False)["rigidness"] == 0).all()
    drawn = inf.infer(prop, logits, kin, params=False, generator=torch.Generator().manual_seed(1))["params"]
    assert ((drawn >= -15) & (drawn <= -5)).all() and not torch.allclose(drawn, full["params"])


def test_rigidness_alone_equals_the_full_inference_s():
    torch.manual_seed(0)
    _, inf = _modules()
    assert inf.param_encoder is not None  # the path that skips the second encoder
    prop, logits = torch.rand(3, 6, 24, 3), torch.randn(3, 6, 24, 2)
    kin = torch.zeros(24, dtype=torch.bool)
    with torch.no_grad():
        assert torch.equal(inf.rigidness(prop, logits, kin), inf.infer(prop, logits, kin)["rigidness"])


@pytest.mark.parametrize("name", ABLATIONS)
def test_ablation_flags_agree_with_the_config_group(name):
    assert OmegaConf.load(REPO / f"conf/ablation/{name}.yaml") == ablation_config(name)


def test_sliding_window_keeps_the_last_frame_of_each_window():
    torch.manual_seed(0)
    model = VisualPrior(n_particles=5, n_instances=2, channels=[4, 4, 4, 4], hidden=8).eval()
    images = torch.randint(0, 255, (2, 7, 120, 160, 3), dtype=torch.uint8)
    pos, logits = propose_videos(model, images, batch_size=3)
    with torch.no_grad():
        first, _ = model.propose(images[:1, 0:4])
        third, g = model.propose(images[1:, 2:6])
    assert torch.allclose(pos[0, :4], first[0]) and torch.allclose(pos[1, 5], third[0, -1]) and torch.allclose(logits[1, 5], g[0, -1])


def _gradient_norm(weights) -> float:
    return torch.nn.utils.get_total_norm([w.grad for w in weights]).item()


def test_norm_clipping_clips_each_network_on_its_own():
    """P's small gradient keeps its size when the refinement network's is clipped (no shared factor)."""
    _, inf = _modules(separate_param_net=True)
    pathway, rest = inf.pathway_and_rest()
    for weights, value in ((pathway, 1e-3), (rest, 10.0)):
        for w in weights:
            w.grad = torch.full_like(w, value)
    before = [w.grad.clone() for w in pathway]
    inf.configure_gradient_clipping(inf.configure_optimizers(), gradient_clip_val=1.0, gradient_clip_algorithm="norm")
    assert all(torch.equal(w.grad, g) for w, g in zip(pathway, before))
    assert _gradient_norm(rest) == pytest.approx(1.0, rel=1e-5)
    for w in pathway:  # a large P gradient is clipped to the same norm, on its own
        w.grad = torch.full_like(w, 10.0)
    inf.configure_gradient_clipping(inf.configure_optimizers(), gradient_clip_val=1.0, gradient_clip_algorithm="norm")
    assert _gradient_norm(pathway) == pytest.approx(1.0, rel=1e-5) and _gradient_norm(rest) == pytest.approx(1.0, rel=1e-5)


def _composed(*overrides: str):
    with initialize_config_dir(config_dir=str(REPO / "conf"), version_base="1.3"):
        return compose("config", overrides=["experiment=none", *overrides])


def test_the_config_composes_the_module_from_its_parts():
    """model.inference.net, as the config groups compose it, builds the module train_inference builds: each part
    the group's class with the config's options; the option dataclasses' defaults are the config's."""
    from vgpl.checkpoint import scene_of
    from vgpl.models.rigidness_estimator import BernoulliRigidness, BlendRigidness
    from vgpl.models.rollout_target import ProposalsTarget, TruthTarget
    from vgpl.models.training_scheme import JointScheme, PaperScheme
    from vgpl.tasks.train_inference import inference_module as from_config

    cfg = _composed()
    net = cfg.model.inference.net
    model = from_config(cfg, scene_of(cfg))
    assert isinstance(model.scheme, PaperScheme) and isinstance(model.estimator, BlendRigidness) and isinstance(model.target, TruthTarget)
    assert model.target.refine_weight == net.target.refine_weight == 1.0 and model.hparams.horizon == cfg.model.inference.horizon
    assert model.encoder_options == Encoder(**net.encoder) == Encoder() and model.training_runs == LossRuns(**net.training) == LossRuns()
    assert model.configure_optimizers().param_groups[0]["lr"] == net.optimizer.lr
    assert len(inspect.signature(InferenceModule).parameters) <= 10  # the parts, not their options
    joint = from_config(_composed("inference_scheme=joint", "model.inference.net.scheme.start=both", "rollout_target=proposals",
                                  "rigidness_estimator=bernoulli", "model.inference.net.training.refined_steps=null",
                                  "model.inference.net.training.truth_steps=null"), scene_of(cfg))
    assert isinstance(joint.scheme, JointScheme) and joint.scheme.start == "both"
    assert isinstance(joint.target, ProposalsTarget) and isinstance(joint.estimator, BernoulliRigidness)
    with pytest.raises(ValueError, match="inference_scheme=paper .* rollout_target=truth"):  # a combination that cannot work
        from_config(_composed("rollout_target=proposals"), scene_of(cfg))


def test_param_rotation_turns_only_what_the_parameter_encoder_sees_in_training():
    """param_rotation: in training P is read from the scene turned about the vertical axis (so two
    draws differ, and equal P of the proposals turned by hand), while dX and Q, and P in eval, are
    read from the proposals as they are."""
    torch.manual_seed(0)
    _, plain = _modules(param_rotation=False)
    _, turned = _modules(param_rotation=True)
    turned.load_state_dict(plain.state_dict())
    x, g, kin = torch.rand(2, 6, 24, 3) - 0.5, torch.softmax(torch.randn(2, 24, 2), -1), torch.zeros(24, dtype=torch.bool)
    turned.eval()
    assert torch.equal(turned(x, g, kin)["params"], plain.eval()(x, g, kin)["params"])
    turned.train()
    torch.manual_seed(1)
    first = turned(x, g, kin)
    torch.manual_seed(1)
    angle = torch.rand(2) * (2 * math.pi)
    by_hand = plain.eval()(about_vertical(x, angle), g, kin)["params"]
    assert torch.allclose(first["params"], by_hand, atol=1e-6) and not torch.allclose(first["params"], plain(x, g, kin)["params"])
    assert torch.equal(first["refine"], plain(x, g, kin)["refine"]) and torch.equal(first["rigidness"], plain(x, g, kin)["rigidness"])
    assert not torch.allclose(turned(x, g, kin)["params"], first["params"])  # a new angle each call
    with pytest.raises(ValueError, match="param_rotation=true .* needs .*separate_param_net=true"):
        _modules(param_rotation=True, separate_param_net=False)


def test_proposal_jitter_draws_one_std_per_window_up_to_the_maximum():
    """add_proposal_jitter: every frame and particle its own draw (it shows as motion), with one std
    per window uniform in [0, max_std]: the stds' mean is max_std / 2 and none exceeds it."""
    from vgpl.models.inference import add_proposal_jitter

    torch.manual_seed(0)
    x = torch.rand(400, 6, 50, 3)
    noise = add_proposal_jitter(x, 0.002) - x
    per_window = noise.std((1, 2, 3))
    assert per_window.max() < 0.002 * 1.05 and per_window.min() < 0.0002
    assert abs(float(per_window.mean()) - 0.001) < 0.0001
    lag1 = torch.corrcoef(torch.stack([noise[:, 1:].flatten(), noise[:, :-1].flatten()]))[0, 1]
    assert abs(float(lag1)) < 0.01  # independent from frame to frame: it adds frame-to-frame motion


def test_proposal_noise_enters_the_training_step_only():
    """proposal_noise: the training step's loss sees jittered proposals (two steps differ), the
    validation loss the proposals as they are (equal to a module without it); 0 is the paper's."""
    torch.manual_seed(0)
    dyn, plain = _modules()
    _, noisy = _modules(proposal_noise=0.01)
    noisy.load_state_dict(plain.state_dict())
    noisy.attach_dynamics(dyn)  # the same frozen prior
    batch = _batch()
    torch.testing.assert_close(noisy._losses(batch)["loss"], plain._losses(batch)["loss"])
    torch.testing.assert_close(plain._losses(batch, noise=True)["loss"], plain._losses(batch)["loss"])
    assert not torch.allclose(noisy._losses(batch, noise=True)["loss"], noisy._losses(batch, noise=True)["loss"])
    assert OmegaConf.load(REPO / "conf/model/vgpl.yaml").inference.net.training.proposal_noise == 0.0
    with pytest.raises(ValueError, match=r"proposal_noise=-0\.001, expected a std in metres >= 0"):
        _modules(proposal_noise=-0.001)


@pytest.mark.parametrize("start", ["refined", "both"])
def test_training_on_proposals_reads_no_trajectory_and_rolls_against_the_proposals(start):
    """rollout_target=proposals: with every non-actuated true position NaN, the loss is finite and
    its gradient reaches dX, Q and P; it is the rollout error against the proposals' frames (from
    the refined start, and with ``both`` also from the proposals' own first frames)."""
    torch.manual_seed(0)
    _, inf = _modules(rollout_target="proposals", refine_weight=0.0, trajectory_start=start)
    batch = _batch()
    batch["kinematic"][:, 0] = True  # an actuated particle: its true positions are the actions'
    batch["target_proposals"] = torch.cat([batch["proposals"], torch.rand(2, 2, 24, 3)], 1)
    batch["positions"][:, :, 1:] = float("nan")
    losses = inf._losses(batch)
    assert torch.isfinite(losses["loss"])
    losses["loss"].backward()
    assert all(float(head.lins[-1].weight.grad.abs().sum()) > 0 for head in (inf.refine_head, inf.rigid_head, inf.param_head))
    # the same rollout loss as the trajectory-trained module's when the "truth" is the proposals
    torch.manual_seed(0)
    _, twin = _modules(refine_weight=0.0, trajectory_start=start)
    twin.load_state_dict(inf.state_dict())
    twin_batch = dict(batch, positions=torch.where(batch["kinematic"][0][None, None, :, None], batch["positions"], batch["target_proposals"]))
    twin_losses = twin._losses(twin_batch)
    for name in ("rollout", "rollout_from_truth") if start == "both" else ("rollout",):
        assert float(twin_losses[name]) == pytest.approx(float(losses[name]), rel=1e-6)


def test_training_on_proposals_has_no_term_that_reads_the_trajectories():
    """The proposals target has no refinement or parameter weight to set, and the paper's scheme (which
    rolls with the true G, Q and P) is refused with it."""
    for weight in ("refine_weight", "param_weight"):
        with pytest.raises(Exception, match=weight):
            built({"_target_": "vgpl.models.rollout_target.ProposalsTarget", weight: 1.0})
    with pytest.raises(ValueError, match="inference_scheme=paper .* needs .* rollout_target=truth"):
        _modules(rollout_target="proposals", refine_weight=0.0, training_scheme="paper")


def test_rigid_fit_start_rolls_p_from_the_proposals_start_fitted_rigidly_by_the_modules_q(monkeypatch):
    """rigid_fit_start=true: the run P learns from starts at the proposals' first frames with each instance
    the module's Q calls rigid (> 0.5) fitted rigidly (vgpl.nn.rigid_start) by its G, the refined run from the refined frames;
    P still learns; the option refuses any setting where that start is not the proposals'."""
    import vgpl.models.inference as inference

    rolled = []
    monkeypatch.setattr(inference, "rollout_runs", lambda dyn, runs, kinematic: rolled.extend(runs) or inference_rollout_runs(dyn, runs, kinematic))
    torch.manual_seed(0)
    _, inf = _modules(rollout_target="proposals", refine_weight=0.0, trajectory_start="both", rigid_fit_start=True)
    batch = _batch()
    batch["kinematic"][:, 0] = True
    batch["target_proposals"] = torch.cat([batch["proposals"], torch.rand(2, 2, 24, 3)], 1)
    batch["positions"][:, :, 1:] = float("nan")
    inf._losses(batch)["loss"].backward()
    assert float(inf.param_head.lins[-1].weight.grad.abs().sum()) > 0
    h, kinematic = inf.dynamics.hparams.history, batch["kinematic"][0]
    out = inf.infer(batch["proposals"], batch["logits"], kinematic)
    known = torch.where(kinematic[None, None, :, None], batch["positions"][:, :h], batch["target_proposals"][:, :h])  # actuated: the actions'
    fitted = torch.where(kinematic[None, None, :, None], known, rigid_start(known, out["grouping"], (out["rigidness"] > 0.5).float()))
    refined = torch.where(kinematic[None, None, :, None], batch["positions"][:, :h], out["positions"][:, :h])
    starts = [run[0][:, :h].detach() for run in rolled]
    assert len(starts) == 2 and torch.allclose(starts[1], fitted, atol=1e-6) and torch.allclose(starts[0], refined, atol=1e-6)
    assert (fitted - batch["target_proposals"][:, :h]).abs()[:, :, 1:].max() > 0.05  # the fit moved the proposals
    with pytest.raises(ValueError, match="rigid_fit_start=true fits the rigid instances of the proposals' start"):
        _modules(refine_weight=0.0, rigid_fit_start=True, rollout_target="proposals", trajectory_start="refined")


def test_a_checkpoint_of_an_older_constructor_is_named_with_what_to_do(tmp_path):
    """A checkpoint whose hyperparameters this InferenceModule does not take (the flat options it had
    before its parts): one CheckpointError naming the file and asking for a retrain."""
    from vgpl.checkpoint import CheckpointError, load_stage

    _, inf = _modules()
    path = tmp_path / "inference" / "last.ckpt"
    path.parent.mkdir()
    (path.parent / "config.yaml").write_text("stage_class: vgpl.models.inference.InferenceModule\n")
    flat = {"param_low": [-15.0], "param_high": [-5.0], "n_particles": 24, "n_instances": 2, "radius": 0.3, "width": 16, "training_scheme": "joint"}
    torch.save({"state_dict": inf.state_dict(), "hyper_parameters": flat, "pytorch-lightning_version": lightning.__version__}, path)
    with pytest.raises(CheckpointError, match=f"{path}: a InferenceModule checkpoint saved with constructor arguments .* retrain it"):
        load_stage(path, InferenceModule)
