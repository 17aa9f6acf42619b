from __future__ import annotations

import numpy as np
import pytest
import torch

from vgpl.data.schema import DatasetError
from vgpl.data.shard import write_shard
from vgpl.data.trajectories import NormStats, TrajectoryDataModule, TrajectoryWindows, load_split
from vgpl.models.dynamics_prior import add_history_noise
from vgpl.sim.envs import make_scene
from vgpl.tasks.generate import plan_shards, scene_attrs, simulate_shard


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("traj")
    scene = make_scene("mass_rope", n_steps=12)
    for plan in plan_shards(5, 0.8, 2):
        shard = simulate_shard(scene, plan, seed=0, batch_size=2, render=False, device="cpu")
        shard.attrs = {**scene_attrs(scene, 0), "split": plan.split, "shard": plan.index, "config_hash": "x"}
        write_shard(plan.path(root / "mass_rope"), shard)
    return root, scene


def test_windows_cover_every_valid_frame(dataset):
    root, scene = dataset
    train = load_split(root, "mass_rope", "train")
    assert train.positions.shape == (4, 12, 96, 3)
    ds = TrajectoryWindows(train, scene, history=4, horizon=2)
    assert len(ds) == 4 * (12 - 4 - 2 + 1)
    item = ds[0]
    assert item["positions"].shape == (6, 96, 3) and torch.equal(item["positions"], train.positions[0, :6])
    assert item["grouping"].sum(-1).eq(1).all() and item["kinematic"].sum() == 1  # the pin
    late = TrajectoryWindows(train, scene, history=4, horizon=1, start_frame=5)
    assert torch.equal(late[0]["positions"][0], train.positions[0, 5])


def test_window_span_keeps_training_windows_early_and_validation_whole(dataset):
    root, scene = dataset
    train = load_split(root, "mass_rope", "train")
    early = TrajectoryWindows(train, scene, history=4, horizon=2, start_frame=1, span=8)  # frames 1..8
    assert len(early) == 4 * (8 - 4 - 2 + 1)
    assert max(t for _, t in early.index) + 2 == 8  # the last target is frame 8, the span's last
    dm = TrajectoryDataModule(str(root), scene, horizon=1, batch_size=1, train_span=6)
    dm.setup()
    assert len(dm.train_dataloader().dataset) == 4 * (6 - 4 - 1 + 1)
    assert len(dm.val_dataloader().dataset) == 1 * (12 - 4 - 1 + 1)  # validation keeps every window
    with pytest.raises(ValueError, match="window_span=5 \\(frames 0 to 4\\) is too short for history=4 \\+ horizon=2"):
        TrajectoryWindows(train, scene, history=4, horizon=2, span=5)


def test_statistics_come_from_the_training_split_only(dataset):
    root, scene = dataset
    dm = TrajectoryDataModule(str(root), scene)
    dm.setup()
    movable = ~torch.as_tensor(scene.kinematic)
    disp = dm.train.positions[:, 1:, movable] - dm.train.positions[:, :-1, movable]
    assert torch.allclose(dm.stats.disp_std, disp.reshape(-1, 3).std(0), rtol=1e-4)
    assert not torch.allclose(dm.stats.pos_mean, NormStats.from_rollouts(dm.test).pos_mean)


def test_missing_split_is_named(dataset, tmp_path):
    with pytest.raises(DatasetError, match="mass_rope/train: no shard_"):
        load_split(tmp_path, "mass_rope", "train")


def test_history_noise_is_a_random_walk_that_spares_kinematic_particles():
    torch.manual_seed(0)
    history = torch.zeros(2000, 4, 3, 3)
    movable = torch.tensor([True, True, False])
    noisy = add_history_noise(history, torch.tensor([1.0, 2.0, 3.0]), movable)
    assert torch.equal(noisy[:, 0], history[:, 0]) and torch.equal(noisy[:, :, 2], history[:, :, 2])
    last = noisy[:, -1, :2].reshape(-1, 3)
    assert torch.allclose(last.std(0), torch.tensor([1.0, 2.0, 3.0]), rtol=0.05)  # total std at the last frame
    steps = noisy[:, 1:] - noisy[:, :-1]
    assert abs(float(steps[:, :, :2, 0].std()) - 1 / np.sqrt(3)) < 0.02  # equal increments


def test_an_axis_without_motion_gets_a_floored_std():
    from vgpl.data.trajectories import NormStats, Rollouts

    t = torch.arange(10.0)
    pos = torch.zeros(2, 10, 4, 3)
    pos[..., 1] = (-0.5 * 9.8 * (t / 60) ** 2)[None, :, None]  # falls straight down: no x or z motion
    r = Rollouts(pos, torch.zeros(2, 1), torch.zeros(2, 10, 0), torch.zeros(4, dtype=torch.long), torch.ones(1, dtype=torch.bool),
                 torch.zeros(1), torch.ones(1), "x")
    stats = NormStats.from_rollouts(r)
    assert stats.disp_std[0] == pytest.approx(stats.disp_std[1] * 1e-3) and stats.disp_std[1] > 1e-3


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    root = tmp_path_factory.mktemp("video")
    scene = make_scene("mass_rope", n_steps=6)
    for plan in plan_shards(6, 1.0, 2):  # 3 train shards of 2 videos
        shard = simulate_shard(scene, plan, seed=0, batch_size=2, render=True, device="cpu")
        shard.attrs = {**scene_attrs(scene, 0), "split": plan.split, "shard": plan.index, "config_hash": "x"}
        write_shard(plan.path(root / "mass_rope"), shard)
    return root


def test_videos_are_read_only_as_far_as_asked(rendered):
    """load_split reads the first max_rollouts videos straight into one array, in rollout order."""
    from vgpl.data.shard import read_shard

    files = sorted((rendered / "mass_rope" / "train").glob("shard_*.h5"))
    whole = np.concatenate([read_shard(f).images for f in files])
    assert whole.shape[:2] == (6, 6)
    every = load_split(rendered, "mass_rope", "train", images=True)
    assert torch.equal(every.images, torch.from_numpy(whole)) and every.rollout_ids.tolist() == list(range(6))
    three = load_split(rendered, "mass_rope", "train", images=True, max_rollouts=3)
    assert torch.equal(three.images, torch.from_numpy(whole[:3])) and torch.equal(three.positions, every.positions[:3])
    first = read_shard(files[1], rollouts=1, frames=4)
    assert first.images.shape[:2] == (1, 4) and np.array_equal(first.images, whole[2:3, :4]) and first.rollout_ids.tolist() == [2]


def test_streamed_videos_give_the_same_windows_as_videos_in_memory(rendered):
    """stream=True leaves the video in its files; every window, also read in a DataLoader worker
    (which gets a pickled copy with no open files), equals the one cut from the in-memory array."""
    import dataclasses
    import pickle

    from torch.utils.data import DataLoader

    from vgpl.data.flow_windows import FlowWindows
    from vgpl.data.video import VideoWindows

    memory = load_split(rendered, "mass_rope", "train", images=True, max_rollouts=5)
    streamed = load_split(rendered, "mass_rope", "train", images=True, max_rollouts=5, stream=True)
    assert streamed.images.shape == tuple(memory.images.shape) and len(streamed.images) == 5  # 5 of the 6 videos, 3 files
    assert torch.equal(streamed.images[4, 3], memory.images[4, 3]) and torch.equal(streamed.images[2, 1:5], memory.images[2, 1:5])
    assert torch.equal(streamed.positions, memory.positions)
    copy = dataclasses.replace(streamed, images=pickle.loads(pickle.dumps(streamed.images)))  # streamed.images has files open now
    a, b = VideoWindows(memory, frames=4), VideoWindows(copy, frames=4)
    assert len(a) == len(b) == 5 * (6 - 4 + 1)
    for k in range(len(a)):
        assert torch.equal(a[k]["frames"], b[k]["frames"]) and torch.equal(a[k]["positions"], b[k]["positions"])
    worker = next(iter(DataLoader(VideoWindows(streamed, frames=4), batch_size=len(a), num_workers=1)))
    assert torch.equal(worker["frames"], torch.stack([a[k]["frames"] for k in range(len(a))]))
    flow_a, flow_b = (FlowWindows(r, make_scene("mass_rope").camera, observed=3, stride=1) for r in (memory, streamed))  # DensePhysNet's
    assert len(flow_a) == len(flow_b) == 5 * 3  # windows of 3 + 1 frames from frames 0-2
    assert all(torch.equal(flow_a[k]["frames"], flow_b[k]["frames"]) for k in range(len(flow_a)))
    with pytest.raises(IndexError, match=r"videos\[rollout, frames\]"):
        streamed.images[0]


def test_streaming_a_split_without_video_names_the_file(dataset):
    root, _ = dataset
    with pytest.raises(DatasetError, match=r"train/shard_00000\.h5: key 'images' missing: the dataset was generated with data.render=false"):
        load_split(root, "mass_rope", "train", images=True, stream=True)


@pytest.mark.parametrize("stream", [False, True])
def test_a_shard_whose_frames_differ_from_the_splits_is_named(rendered, tmp_path, stream):
    """Both video readers refuse a split whose shards hold frames of different sizes, naming the
    shard and both shapes (a dataset rendered at two resolutions, or a shard from another run)."""
    import shutil

    import h5py

    root = tmp_path / "mixed"
    shutil.copytree(rendered, root)
    odd = root / "mass_rope" / "train" / "shard_00001.h5"
    with h5py.File(odd, "a") as h:
        images = h["images"][:, :, :, :-8]  # 8 pixels narrower
        del h["images"]
        h.create_dataset("images", data=images)
    r, t, height, width, _ = images.shape
    with pytest.raises(DatasetError, match=rf"shard_00001.h5: 'images' of shape \[R, {t}, {height}, {width}, 3\], "
                                           rf"the split's first shard has \[R, {t}, {height}, {width + 8}, 3\]"):
        load_split(root, "mass_rope", "train", images=True, stream=stream)


def test_first_rollout_skips_the_first_videos_in_memory_and_streamed(rendered):
    """load_split(first_rollout=k): the rollouts from the k-th on (here from the middle of a shard
    file), the same rows and videos as a whole read cut at k, in memory and streamed; none left
    is an error naming the folder and the option."""
    every = load_split(rendered, "mass_rope", "train", images=True)
    for first, count in ((3, 2), (1, None), (4, 2)):
        part = load_split(rendered, "mass_rope", "train", images=True, max_rollouts=count, first_rollout=first)
        rows = slice(first, None if count is None else first + count)
        assert part.rollout_ids.tolist() == every.rollout_ids[rows].tolist()
        assert torch.equal(part.positions, every.positions[rows]) and torch.equal(part.images, every.images[rows])
        streamed = load_split(rendered, "mass_rope", "train", images=True, max_rollouts=count, stream=True, first_rollout=first)
        assert len(streamed.images) == len(part.images)
        assert all(torch.equal(streamed.images[r, 0:6], part.images[r]) for r in range(len(part.images)))
    with pytest.raises(DatasetError, match=r"mass_rope/train: 6 rollouts, none from first_rollout=6 on"):
        load_split(rendered, "mass_rope", "train", first_rollout=6)


def test_the_visual_stage_holds_out_the_inference_modules_videos(rendered, tmp_path, caplog):
    """model.visual.first_rollout reaches the visual stage's training videos, and export_proposals
    warns when the visual prior learned from any of the inference module's videos."""
    from omegaconf import OmegaConf

    from tests.conftest import REPO
    from vgpl.data.video import VideoDataModule
    from vgpl.tasks.train_visual import held_out_videos

    for split in ("train", "test"):  # the six videos as both splits
        (tmp_path / "mass_rope").mkdir(exist_ok=True)
        (tmp_path / "mass_rope" / split).symlink_to(rendered / "mass_rope" / "train")
    dm = VideoDataModule(str(tmp_path), "mass_rope", first_rollout=4)
    dm.setup()
    assert dm.train.rollout_ids.tolist() == [4, 5] and len(dm.test.rollout_ids) == 6
    assert OmegaConf.load(REPO / "conf/model/vgpl.yaml").visual.first_rollout == 0
    trained = OmegaConf.create({"model": {"visual": {"first_rollout": 300}}})
    with caplog.at_level("WARNING"):
        assert held_out_videos(trained, 300) == 300
        assert caplog.text == ""
        assert held_out_videos(OmegaConf.create({"model": {"visual": {}}}), 300) == 0  # a checkpoint from before the key
    assert ("the visual prior trained on training videos from 0 on, among them the inference module's (model.inference.max_rollouts=300): "
            "their proposals can fit better than the test videos'; model.visual.first_rollout=300 holds them out") in caplog.text


def test_videos_come_in_rollout_order_whatever_the_files_order(rendered, tmp_path):
    """Shard files whose names sort against their rollout ids (here the first and last of three
    swapped): load_split still gives rollouts, and their videos, in rollout order."""
    files = sorted((rendered / "mass_rope" / "train").glob("shard_*.h5"))
    folder = tmp_path / "mass_rope" / "train"
    folder.mkdir(parents=True)
    for name, source in zip(files, [files[2], files[1], files[0]]):
        (folder / name.name).symlink_to(source)
    every = load_split(rendered, "mass_rope", "train", images=True)
    for stream in (False, True):
        swapped = load_split(tmp_path, "mass_rope", "train", images=True, stream=stream, first_rollout=1)
        assert swapped.rollout_ids.tolist() == [1, 2, 3, 4, 5] and torch.equal(swapped.positions, every.positions[1:])
        assert all(torch.equal(swapped.images[r, 0:6], every.images[r + 1]) for r in range(5))
