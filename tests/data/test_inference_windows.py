from __future__ import annotations

import pytest
import torch

from vgpl.data.inference_windows import InferenceWindows
from vgpl.data.proposals import Proposals
from vgpl.data.schema import DatasetError
from vgpl.data.trajectories import Rollouts
from vgpl.sim.envs import make_scene


def _data(n_frames=60, proposal_frames=60, env="rigid_fall"):
    scene = make_scene(env, n_steps=n_frames)
    r, n, m = 2, scene.n_particles, scene.n_instances
    rollouts = Rollouts(torch.rand(r, n_frames, n, 3), torch.as_tensor(scene.param_low).repeat(r, 1), torch.zeros(r, n_frames, scene.action_dim),
                        torch.as_tensor(scene.instance), torch.as_tensor(scene.rigid), torch.as_tensor(scene.param_low),
                        torch.as_tensor(scene.param_high), scene.name, torch.arange(r))
    proposals = Proposals(torch.rand(r, proposal_frames, n, 3), torch.randn(r, proposal_frames, n, m), torch.arange(r), {})
    return scene, rollouts, proposals


def test_windows_need_proposals_only_as_far_as_the_last_observed_frame():
    """export_proposals writes start_frame + window_span + observed frames, not whole videos."""
    scene, rollouts, proposals = _data(proposal_frames=2 + 20 + 10)
    ds = InferenceWindows(rollouts, proposals, scene, observed=10, horizon=5, start_frame=2, span=20)
    assert [s for _, s in ds.index[:21]] == list(range(2, 23)) and len(ds) == 2 * 21
    item = ds[len(ds) - 1]  # the last window: frames 22..31 observed, truth to frame 36
    assert item["proposals"].shape[0] == 10 and item["positions"].shape[0] == 15
    assert torch.equal(item["proposals"], proposals.positions[1, 22:32])


def test_items_carry_the_true_rigidness_per_instance_for_the_logged_reading():
    scene, rollouts, proposals = _data(env="fluid_cube")
    batch = torch.utils.data.default_collate([InferenceWindows(rollouts, proposals, scene, observed=10, horizon=5)[k] for k in (0, 7)])
    assert batch["rigid"].tolist() == [[True, False]] * 2  # FluidCube: the cube, then the fluid


def test_too_short_proposals_name_the_fix():
    scene, rollouts, proposals = _data(proposal_frames=31)
    with pytest.raises(DatasetError, match="cover the first 31 frames.*need 32.*re-export with task=export_proposals"):
        InferenceWindows(rollouts, proposals, scene, observed=10, horizon=5, start_frame=2, span=20)


def test_export_covers_the_frames_the_inference_windows_read():
    from omegaconf import OmegaConf

    from vgpl.tasks.train_visual import proposal_frames

    cfg = OmegaConf.create({"env": {"start_frame": 2}, "model": {"inference": {"observed": 10, "horizon": 5, "window_span": 20}}})
    assert proposal_frames(cfg) == 32  # exactly what the windows above need
    cfg.model.inference.net = {"target": {"_target_": "vgpl.models.rollout_target.ProposalsTarget"}}
    assert proposal_frames(cfg) == 37  # training without trajectories rolls against the 5 frames after them too
    cfg.model.inference.window_span = None
    assert proposal_frames(cfg) is None  # windows anywhere: whole videos


def test_windows_for_training_without_trajectories_carry_the_future_frames_proposals():
    scene, rollouts, proposals = _data(proposal_frames=2 + 20 + 10 + 5)
    ds = InferenceWindows(rollouts, proposals, scene, observed=10, horizon=5, start_frame=2, span=20, target_proposals=True)
    item = ds[len(ds) - 1]  # frames 22..31 observed, 32..36 rolled
    assert torch.equal(item["target_proposals"], proposals.positions[1, 22:37]) and torch.equal(item["proposals"], proposals.positions[1, 22:32])
    assert "target_proposals" not in InferenceWindows(rollouts, proposals, scene, observed=10, horizon=5, start_frame=2, span=20)[0]
    with pytest.raises(DatasetError, match="cover the first 37 frames.*observed \\+ 5 future \\(rollout_target=proposals\\) need 38"):
        InferenceWindows(rollouts, proposals, scene, observed=10, horizon=5, start_frame=2, span=21, target_proposals=True)


def test_truth_proposals_without_noise_are_the_recorded_particles_and_their_instances():
    from vgpl.data.proposals import truth_proposals

    scene, rollouts, _ = _data(n_frames=12)
    pos, logits = truth_proposals(rollouts.positions, rollouts.instance, scene.n_instances)
    assert torch.equal(pos, rollouts.positions) and logits.shape == (2, 12, scene.n_particles, scene.n_instances)
    grouping = torch.softmax(logits, -1).mean(1)  # what InferenceModule.infer makes of them: the true G
    assert torch.allclose(grouping, torch.nn.functional.one_hot(rollouts.instance, scene.n_instances).float().expand(2, -1, -1), atol=1e-4)
    with pytest.raises(ValueError, match="noise_std=-0.1: expected a standard deviation >= 0"):
        truth_proposals(rollouts.positions, rollouts.instance, scene.n_instances, -0.1)


@pytest.mark.parametrize("val_span, starts", [(None, [2, 12, 22]), (0, [2]), (10, [2, 12])])
def test_validation_windows_can_be_the_evaluations_alone(val_span, starts):
    """val_window_span=0: one validation window per test video, at start_frame, where task=evaluate
    observes; null keeps the training span (every ``observed`` frames)."""
    from vgpl.data.inference_windows import InferenceDataModule

    scene, rollouts, proposals = _data()
    dm = InferenceDataModule("unused", scene, observed=10, horizon=5, start_frame=2, span=20, val_span=val_span)
    dm.test, dm.test_proposals = rollouts, proposals
    assert dm.val_dataloader().dataset.index == [(r, s) for r in range(2) for s in starts]


def test_a_negative_validation_span_is_refused_by_name():
    from vgpl.data.inference_windows import InferenceDataModule

    with pytest.raises(ValueError, match="model.inference.val_window_span=-1: expected a frame count >= 0"):
        InferenceDataModule("unused", _data()[0], val_span=-1)


@pytest.mark.parametrize("env, start", [("rigid_fall", 0), ("fluid_cube", 20), ("mass_rope", 20)])
def test_the_standard_preset_validates_where_evaluate_observes(env, start):
    """One validation window per test video, at the env's start_frame."""
    from hydra import compose, initialize_config_dir

    from tests.conftest import REPO
    from vgpl.tasks.train_inference import inference_datamodule

    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=[f"env={env}", "experiment=standard"])
    scene, rollouts, proposals = _data(n_frames=80, proposal_frames=80, env=env)
    dm = inference_datamodule(cfg, scene)
    dm.test, dm.test_proposals = rollouts, proposals
    assert dm.val_dataloader().dataset.index == [(0, start), (1, start)]
    assert cfg.model.inference.net.encoder.separate_param_net  # the paper's two encoders


def test_proposals_of_other_rollouts_are_refused_by_file_name(tmp_path):
    """split_with_proposals (the DataModule's and the diagnostics' loader) pairs a split with its
    proposals only when their rollout_ids agree: the first R rollouts, or R consecutive later ones."""
    from vgpl.data.inference_windows import proposals_path, split_with_proposals
    from vgpl.data.proposals import write_proposals
    from vgpl.data.shard import write_shard
    from vgpl.data.trajectories import load_split
    from vgpl.tasks.generate import plan_shards, scene_attrs, simulate_shard

    scene = make_scene("mass_rope", n_steps=12)
    for plan in plan_shards(5, 0.8, 2):
        shard = simulate_shard(scene, plan, seed=0, batch_size=2, render=False, device="cpu")
        shard.attrs = {**scene_attrs(scene, 0), "split": plan.split, "shard": plan.index, "config_hash": "x"}
        write_shard(plan.path(tmp_path / "mass_rope"), shard)
    ids = torch.tensor([0, 1, 2])  # the first 3 training rollouts
    path = proposals_path(tmp_path, "mass_rope", "train")
    write_proposals(path, Proposals(torch.rand(3, 12, 95, 3), torch.zeros(3, 12, 95, 2), ids, {}))
    rollouts, proposals = split_with_proposals(tmp_path, "mass_rope", "train")
    assert rollouts.positions.shape[0] == 3 and torch.equal(rollouts.rollout_ids, proposals.rollout_ids)
    write_proposals(path, Proposals(torch.rand(3, 12, 95, 3), torch.zeros(3, 12, 95, 2), ids + 1, {}))  # a later block: rollouts 1-3
    rollouts, proposals = split_with_proposals(tmp_path, "mass_rope", "train")
    assert rollouts.rollout_ids.tolist() == [1, 2, 3] and torch.equal(rollouts.rollout_ids, proposals.rollout_ids)
    assert torch.equal(rollouts.positions, load_split(tmp_path, "mass_rope", "train").positions[1:4])
    for wrong in (ids.flip(0), ids + 2):  # out of order; past the split's 4 rollouts
        write_proposals(path, Proposals(torch.rand(3, 12, 95, 3), torch.zeros(3, 12, 95, 2), wrong, {}))
        with pytest.raises(DatasetError, match=r"mass_rope/proposals/train.h5: 'rollout_ids' do not match the dataset's; re-export"):
            split_with_proposals(tmp_path, "mass_rope", "train")


def test_exported_proposals_are_taken_by_rollout_id_and_refused_by_file_name(tmp_path):
    """eval.proposals=exported reads the test split's proposals file: the rows of the evaluated
    videos in their order, and one error naming the file where it cannot serve them."""
    from vgpl.data.proposals import exported_proposals, write_proposals

    positions, logits = torch.rand(3, 12, 95, 3), torch.rand(3, 12, 95, 2)
    path = write_proposals(tmp_path / "test.h5", Proposals(positions, logits, torch.tensor([7, 3, 5]), {"source": "visual"}))
    got = exported_proposals(path, torch.tensor([5, 7]), frames=10)
    assert got.rollout_ids.tolist() == [5, 7] and got.positions.shape == (2, 10, 95, 3)
    torch.testing.assert_close(got.positions, positions[[2, 0], :10])
    torch.testing.assert_close(got.logits, logits[[2, 0], :10])
    with pytest.raises(DatasetError, match=r"test.h5: no proposals for rollout_ids \[9\] of the test split \(3 exported\)"):
        exported_proposals(path, torch.tensor([5, 9]), frames=10)
    with pytest.raises(DatasetError, match=r"test.h5: proposals of 12 frames, the evaluation reads 13 .*window_span"):
        exported_proposals(path, torch.tensor([5]), frames=13)
    truth = write_proposals(tmp_path / "truth.h5", Proposals(positions, logits, torch.tensor([7, 3, 5]), {"source": "truth"}))
    with pytest.raises(DatasetError, match=r"truth.h5: truth proposals"):
        exported_proposals(truth, torch.tensor([5]), frames=10)


def test_pooled_windows_read_the_slots_and_a_visual_file_without_them_is_refused(tmp_path):
    """model.inference.window_pool=mean: each training window's proposals are pooled over the
    visual windows that end within it; a visual prior's file exported before slots were kept is
    refused by name, the recorded particles (no windows) are read as they are."""
    from vgpl.data.inference_windows import InferenceDataModule, proposals_path
    from vgpl.data.proposals import write_proposals
    from vgpl.data.window_pool import pool_windows

    scene, rollouts, proposals = _data(proposal_frames=32)
    proposals.slots = torch.rand(2, 32, 4, scene.n_particles, 3)
    ds = InferenceWindows(rollouts, proposals, scene, observed=10, horizon=5, start_frame=2, span=20, window_pool="mean")
    r, s = ds.index[7]
    torch.testing.assert_close(ds[7]["proposals"], pool_windows(proposals.positions[r, s : s + 10], proposals.slots[r, s : s + 10], "mean"))
    assert not torch.allclose(ds[7]["proposals"], proposals.positions[r, s : s + 10])
    with pytest.raises(ValueError, match="model.inference.window_pool='first'"):
        InferenceWindows(rollouts, proposals, scene, observed=10, horizon=5, window_pool="first")
    for split in ("train", "test"):
        write_proposals(proposals_path(tmp_path, scene.name, split), Proposals(proposals.positions, proposals.logits, torch.arange(2), {"source": "visual"}))
    dm = InferenceDataModule(str(tmp_path), scene, observed=10, horizon=5, window_pool="mean")
    with pytest.raises(DatasetError, match=r"rigid_fall/proposals/train.h5: no 'slots' .*window_pool='mean' needs them; re-export"):
        dm.setup()
