"""VisualPrior's learning-rate anneal (model.visual.net.lr_anneal_steps): constant, then a half
cosine to zero over the last steps of trainer.max_steps, by global step, so resumed fits match;
under a trainer.max_time over the same share of the time budget too, whichever ends first."""

from __future__ import annotations

import lightning as L
import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from tests.models.learning_rate_callbacks import BatchClock, LearningRates
from vgpl.models.step_learning_rate import annealed_fraction, unfinished_anneal
from vgpl.models.visual_prior import VisualPrior


def test_the_anneal_is_flat_then_a_half_cosine_ending_at_zero():
    assert [annealed_fraction(s, 10, 4) for s in (0, 5, 6)] == [1.0, 1.0, 1.0]
    assert annealed_fraction(8, 10, 4) == pytest.approx(0.5)
    assert annealed_fraction(7, 10, 4) == pytest.approx(0.5 * (1 + 2 ** -0.5))
    assert annealed_fraction(10, 10, 4) == pytest.approx(0.0)
    with pytest.raises(ValueError, match=r"model\.visual\.net\.lr_anneal_steps=4 needs a finite model\.visual\.trainer\.max_steps"):
        annealed_fraction(0, -1, 4)


def test_under_a_time_budget_the_anneal_follows_whichever_schedule_is_further_on():
    """Anneal the last 4 of 10 steps, and so the last 40% of a 100 s budget: at step 2 after 80 s
    the clock is halfway through its anneal while the steps have not begun theirs."""
    assert annealed_fraction(2, 10, 4, elapsed_s=80.0, budget_s=100.0) == pytest.approx(0.5)
    assert annealed_fraction(2, 10, 4, elapsed_s=50.0, budget_s=100.0) == pytest.approx(1.0)
    assert annealed_fraction(8, 10, 4, elapsed_s=10.0, budget_s=100.0) == pytest.approx(0.5)  # the steps lead
    assert annealed_fraction(3, 10, 4, elapsed_s=100.0, budget_s=100.0) == pytest.approx(0.0)  # the clock ran out: zero
    assert annealed_fraction(3, 10, 4, elapsed_s=None, budget_s=None) == 1.0  # no max_time: by step alone


def test_a_fit_stopped_before_its_anneal_ended_says_so_and_how_to_finish():
    """A time cap can stop a fit before max_steps (a 7,000-step run stopped at 5,441 with
    lr_anneal_steps=2000), and its last.ckpt is then not the annealed prior: the warning says so."""
    mid = unfinished_anneal("visual", 2000, 5441, 7000)
    assert mid.startswith("visual: stopped at step 5441 of 7000, mid-anneal, at 88% of lr (model.visual.net.lr_anneal_steps=2000)")
    assert "ckpt_path=last model.visual.trainer.max_time=null" in mid
    assert "before its learning-rate anneal began" in unfinished_anneal("visual", 2000, 4000, 7000)
    assert unfinished_anneal("visual", 2000, 7000, 7000) is None  # finished
    assert unfinished_anneal("visual", 0, 10, 7000) is None  # no anneal (the paper's constant rate)


def fit(max_steps: int, root, ckpt_path=None, max_epochs: int = -1, anneal_steps: int = 4, clock_s: float | None = None,
        n_videos: int = 8) -> list[float]:
    torch.manual_seed(0)
    videos = [{"frames": torch.randint(0, 255, (4, 16, 20, 3), dtype=torch.uint8), "positions": torch.randn(4, 3, 3),
               "instance": torch.tensor([0, 0, 1])} for _ in range(n_videos)]
    model = VisualPrior(n_particles=3, n_instances=2, channels=[4, 4], pooled=[1, 1], hidden=8, lr=1e-3, lr_anneal_steps=anneal_steps)
    rates = LearningRates()
    clock = [] if clock_s is None else [BatchClock(clock_s)]
    trainer = L.Trainer(max_steps=max_steps, max_epochs=max_epochs, logger=False, enable_progress_bar=False, enable_model_summary=False,
                        default_root_dir=root, callbacks=[rates, *clock], enable_checkpointing=False)
    trainer.fit(model, DataLoader(videos, batch_size=2), ckpt_path=ckpt_path)
    trainer.save_checkpoint(root / "last.ckpt")
    return rates.first_group()


def test_a_fit_resumed_past_its_first_max_steps_anneals_as_an_uninterrupted_one(tmp_path):
    """Steps 0-3 of an 8-step fit run at lr; steps 4-7 at lr x 0.5 (1 + cos(pi k / 4)), k = 0..3.
    A 5-step fit resumed to 8 steps takes its steps 5-7 at the same rates."""
    whole = fit(8, tmp_path / "whole")
    expected = [1e-3] * 5 + [1e-3 * annealed_fraction(s, 8, 4) for s in (5, 6, 7)]
    assert whole == pytest.approx(expected)
    assert whole[-1] == pytest.approx(1e-3 * 0.5 * (1 + torch.cos(torch.tensor(torch.pi * 3 / 4)).item()))
    first = fit(5, tmp_path / "cut")  # its own, shorter schedule: full rate at steps 0-1, lower from step 2
    assert first[0] == pytest.approx(1e-3) and first[-1] < 1e-3
    resumed = fit(8, tmp_path / "resumed", ckpt_path=tmp_path / "cut" / "last.ckpt")
    assert resumed == pytest.approx(whole[5:])


def test_the_fit_warns_when_it_stops_before_its_anneal_ends(tmp_path, caplog):
    """One epoch of 4 batches with max_steps=8: the fit stops at step 4, where the anneal of the
    last 4 steps would begin; a fit that reaches max_steps says nothing."""
    with caplog.at_level("WARNING", logger="vgpl.models.step_learning_rate"):
        fit(8, tmp_path / "cut", max_epochs=1)
    assert "visual: stopped at step 4 of 8, before its learning-rate anneal began (model.visual.net.lr_anneal_steps=4)" in caplog.text
    caplog.clear()
    with caplog.at_level("WARNING", logger="vgpl.models.step_learning_rate"):
        fit(8, tmp_path / "whole")
    assert "stopped at step" not in caplog.text


def test_a_fit_the_clock_stops_first_ends_annealed_and_resumes_on_the_same_schedule(tmp_path, caplog):
    """max_steps 100 with the last 50 annealed, a 6 s budget on a clock of one second a batch: the
    last half of the budget (3-6 s) is annealed, so batches 3, 4, 5 start at 3, 4, 5 s and take
    lr x 1, 0.75, 0.25, and the clock stops the fit at 6 s, at zero, with no warning. A fit of one
    3-batch epoch resumed from its checkpoint (Timer state: 3 s spent) takes the same last three."""
    with caplog.at_level("WARNING", logger="vgpl.models.step_learning_rate"):
        whole = fit(100, tmp_path / "whole", anneal_steps=50, clock_s=6.0, n_videos=6)
    assert whole == pytest.approx([1e-3, 1e-3, 1e-3, 1e-3, 0.75e-3, 0.25e-3])
    assert "stopped at step" not in caplog.text
    with caplog.at_level("WARNING", logger="vgpl.models.step_learning_rate"):
        first = fit(100, tmp_path / "cut", anneal_steps=50, clock_s=6.0, n_videos=6, max_epochs=1)
    assert first == pytest.approx([1e-3] * 3)
    assert "visual: stopped at step 3 of 100, before its learning-rate anneal began" in caplog.text
    resumed = fit(100, tmp_path / "resumed", anneal_steps=50, clock_s=6.0, n_videos=6, ckpt_path=tmp_path / "cut" / "last.ckpt")
    assert resumed == pytest.approx(whole[3:])


def test_the_encoder_runs_channels_last_and_computes_what_the_nchw_layout_does():
    """The encoder's weights and input are stored channels-last (the fast convolutions' layout,
    benchmarks/visual.py); channel f * 3 + c is frame f's colour c as before, the outputs match
    the same weights run in NCHW, and a state dict saved in NCHW (older checkpoints)
    loads into it and gives the same outputs."""
    torch.manual_seed(0)
    frames = torch.randint(0, 255, (2, 4, 24, 32, 3), dtype=torch.uint8)
    model = VisualPrior(n_particles=5, n_instances=2, channels=[8, 16], pooled=[2, 2], hidden=16).eval()
    x = VisualPrior.to_input(frames)
    assert x.is_contiguous(memory_format=torch.channels_last)
    assert model.encoder[0][0].weight.is_contiguous(memory_format=torch.channels_last)
    assert torch.equal(x[1, 7], frames[1, 2, :, :, 1].float() / 127.5 - 1.0)  # channel 7 = frame 2, green

    nchw = VisualPrior(n_particles=5, n_instances=2, channels=[8, 16], pooled=[2, 2], hidden=16).eval()
    nchw.encoder.to(memory_format=torch.contiguous_format)
    nchw.load_state_dict({k: v.contiguous() for k, v in model.state_dict().items()})
    assert nchw.encoder[0][0].weight.is_contiguous()
    with torch.no_grad():
        expected = nchw.position_head(nchw.encoder(x.contiguous()))
        assert torch.allclose(model.position_head(model.encoder(x)), expected, atol=1e-5)
        loaded = VisualPrior(n_particles=5, n_instances=2, channels=[8, 16], pooled=[2, 2], hidden=16).eval()
        loaded.load_state_dict(nchw.state_dict())
        assert loaded.encoder[0][0].weight.is_contiguous(memory_format=torch.channels_last)
        assert torch.allclose(loaded(frames)[0], model(frames)[0], atol=1e-6)


def test_unproject_inverts_the_cameras_projection():
    from vgpl.sim.envs import make_scene

    camera = make_scene("rigid_fall").camera
    points = torch.tensor([[0.1, 0.3, 0.05], [-0.2, 0.0, 0.4], [0.3, 0.7, -0.1]])
    projected = camera.project(points)
    assert torch.allclose(camera.unproject(projected[:, :2], projected[:, 2]), points, atol=1e-6)


def test_the_spatial_prior_places_each_slot_on_the_cameras_ray_through_its_attended_pixel(tmp_path):
    """architecture=spatial: a slot attending uniformly sits at the image centre at the training
    split's mean depth; in general every slot's world position projects back onto the pixel its
    heatmap attends to, through the camera saved with the checkpoint."""
    from vgpl.checkpoint import load_stage  # noqa: F401  (the loader's class check runs on this class)
    from vgpl.sim.envs import make_scene

    camera = make_scene("rigid_fall").camera
    torch.manual_seed(0)
    model = VisualPrior(n_particles=6, n_instances=2, channels=[4, 8, 8], architecture="spatial", head_width=8).eval()
    model.pos_mean.copy_(torch.tensor([0.1, 0.3, 0.05]))
    model.pos_std.copy_(torch.tensor([0.1, 0.2, 0.1]))
    model.set_camera(camera)
    frames = torch.randint(0, 255, (2, 4, 120, 160, 3), dtype=torch.uint8)
    with torch.no_grad():
        model.slots.heat.weight.zero_()
        model.slots.heat.bias.zero_()
        model.slots.depth.weight.zero_()
        model.slots.depth.bias.zero_()
        centre = camera.project(model.propose(frames)[0].reshape(-1, 3))
    assert torch.allclose(centre[:, :2], torch.tensor([80.0, 60.0]), atol=1e-3)  # (u, v) of the image centre
    mean_depth = camera.project(model.pos_mean[None])[0, 2]
    assert torch.allclose(centre[:, 2], mean_depth, atol=1e-4)

    trained = VisualPrior(n_particles=6, n_instances=2, channels=[4, 8, 8], architecture="spatial", head_width=8).eval()
    trained.pos_mean.copy_(model.pos_mean), trained.pos_std.copy_(model.pos_std)
    trained.set_camera(camera)
    with torch.no_grad():
        positions, logits = trained.propose(frames)
        maps, x = [], trained.to_input(frames)
        for block in trained.trunk:
            x = block(x)
            maps.append(x)
        uv, _, _ = trained.slots(maps[-2], maps[-1], (120, 160))
    assert positions.shape == (2, 4, 6, 3) and logits.shape == (2, 4, 6, 2)
    assert torch.allclose(camera.project(positions.reshape(2, -1, 3))[..., :2], uv, atol=1e-3)
    reloaded = VisualPrior(**trained.hparams).eval()
    reloaded.load_state_dict(trained.state_dict())  # the camera travels with the weights
    assert torch.equal(reloaded.world_to_camera, trained.world_to_camera)
    with torch.no_grad():
        assert torch.allclose(reloaded.propose(frames)[0], positions)
    with pytest.raises(ValueError, match="model.visual.net.architecture='dense': expected paper or spatial"):
        VisualPrior(n_particles=6, n_instances=2, architecture="dense")


def test_rigid_fit_proposes_each_rigid_instance_as_a_rigid_motion_of_its_rest_layout():
    """rigid_fit: a rigid instance's noisy slots are replaced by the best rigid motion of its rest
    layout, which is nearer the truth than the slots; a non-rigid instance's slots stay as they are."""
    from types import SimpleNamespace

    from vgpl.sim.scene import lattice

    cube = lattice((2, 2, 2), 0.1)
    scene = SimpleNamespace(rest_offsets=np.concatenate([cube, np.zeros((3, 3))]).astype(np.float32),
                            instance=np.array([0] * 8 + [1] * 3), rigid=np.array([True, False]))
    model = VisualPrior(n_particles=11, n_instances=2, channels=[4, 4], pooled=[1, 1], hidden=8, rigid_fit=True).eval()
    model.set_structure(scene)
    turn = torch.tensor([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    truth = torch.cat([torch.as_tensor(cube, dtype=torch.float32) @ turn.T + torch.tensor([0.3, 0.5, -0.2]), torch.rand(3, 3)])
    torch.manual_seed(1)
    noisy = truth + 0.01 * torch.randn(11, 3)
    model.forward = lambda frames: (noisy.expand(1, 4, 11, 3), torch.zeros(1, 4, 11, 2))  # a stand-in network
    proposed, _ = model.propose(torch.zeros(1, 4, 8, 8, 3, dtype=torch.uint8))
    cube_out = proposed[0, 0, :8]
    assert torch.allclose(torch.cdist(cube_out, cube_out), torch.cdist(truth[:8], truth[:8]), atol=1e-5)  # exactly the rest shape
    assert float(((cube_out - truth[:8]) ** 2).mean()) < 0.5 * float(((noisy[:8] - truth[:8]) ** 2).mean())
    assert torch.equal(proposed[0, 0, 8:], noisy[8:])  # the free instance as proposed


def test_rigid_pose_places_each_rigid_instances_rest_layout_at_its_attended_centroid():
    """architecture=spatial rigid_pose=true: a rigid instance's particles are its rest layout, turned
    by the instance slot's rotation and centred on the point its heatmap attends to; at the
    identity rotation and uniform attention that is the image centre at the mean depth. The free
    instance's particles keep their own slots."""
    from types import SimpleNamespace

    from vgpl.sim.envs import make_scene
    from vgpl.sim.scene import lattice

    camera = make_scene("rigid_fall").camera
    cube = lattice((2, 2, 2), 0.1)
    scene = SimpleNamespace(rest_offsets=np.concatenate([cube, np.zeros((3, 3))]).astype(np.float32),
                            instance=np.array([0] * 8 + [1] * 3), rigid=np.array([True, False]))
    torch.manual_seed(0)
    model = VisualPrior(n_particles=11, n_instances=2, channels=[4, 8, 8], architecture="spatial", head_width=8, rigid_pose=True).eval()
    model.pos_mean.copy_(torch.tensor([0.1, 0.3, 0.05]))
    model.set_camera(camera)
    model.set_structure(scene)
    frames = torch.randint(0, 255, (2, 4, 120, 160, 3), dtype=torch.uint8)
    with torch.no_grad():
        for conv in (model.poses.heat, model.poses.depth):
            conv.weight.zero_(), conv.bias.zero_()
        model.poses.readout.weight.zero_()
        positions, _ = model.propose(frames)
    placed = positions[:, :, :8]
    assert torch.allclose(placed - placed.mean(2, keepdim=True), torch.as_tensor(cube, dtype=torch.float32).expand_as(placed), atol=1e-5)
    centre = camera.project(placed.mean(2))
    assert torch.allclose(centre[..., :2], torch.tensor([80.0, 60.0]), atol=1e-3)
    assert torch.allclose(centre[..., 2], camera.project(model.pos_mean[None])[0, 2], atol=1e-4)
    assert not torch.allclose(positions[:, :, 8:], placed[:, :, :3])  # the rope-like instance: its own slots
    with pytest.raises(ValueError, match="rigid_pose=true needs model.visual.net.architecture=spatial"):
        VisualPrior(n_particles=11, n_instances=2, rigid_pose=True)
