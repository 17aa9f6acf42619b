from __future__ import annotations

import os
import shutil

import h5py
import numpy as np
import pytest

from tests.tasks.test_generate import config
from vgpl.data.schema import DatasetError, validate
from vgpl.data.shard import read_shard, shard_is_complete, write_shard
from vgpl.data.trajectories import load_split
from vgpl.sim.envs import make_scene
from vgpl.tasks.generate import generate, plan_shards, scene_attrs, simulate_shard


@pytest.fixture(scope="module")
def shard_file(tmp_path_factory):
    scene = make_scene("mass_rope", n_steps=6)
    plan = plan_shards(3, 1.0, 3)[0]
    shard = simulate_shard(scene, plan, seed=0, batch_size=3, render=True, device="cpu")
    shard.attrs = {**scene_attrs(scene, 0), "split": "train", "shard": 0, "config_hash": "abc"}
    return write_shard(tmp_path_factory.mktemp("ds") / "shard_00000.h5", shard)


def test_round_trip(shard_file):
    s = read_shard(shard_file)
    assert s.positions.shape == (3, 6, 96, 3) and s.positions.dtype == np.float32
    assert s.images.shape == (3, 6, 120, 160, 3) and s.images.dtype == np.uint8
    assert s.actions.shape == (3, 6, 6)
    assert list(s.attrs["param_names"]) == ["stiffness"]
    assert s.instance.shape == (96,) and s.rigid.tolist() == [True, False]
    with h5py.File(shard_file) as f:
        assert f["images"].compression == "gzip" and f["images"].chunks == (1, 1, 120, 160, 3)
    assert not shard_file.with_name(shard_file.name + ".tmp").exists()


def test_truncated_file_is_named(shard_file, tmp_path):
    bad = tmp_path / "truncated.h5"
    bad.write_bytes(shard_file.read_bytes()[:4000])
    with pytest.raises(DatasetError, match="truncated.h5.*not a readable HDF5"):
        validate(bad)


def test_foreign_hdf5_is_named(tmp_path):
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = np.zeros(3)
    with pytest.raises(DatasetError, match="other.h5.*format_version"):
        validate(other)


def test_missing_key_is_named(shard_file, tmp_path):
    broken = tmp_path / "broken.h5"
    shutil.copy(shard_file, broken)
    with h5py.File(broken, "a") as f:
        del f["params"]
    with pytest.raises(DatasetError, match="broken.h5.*'params' missing"):
        validate(broken)


def test_inconsistent_shape_is_named(shard_file, tmp_path):
    broken = tmp_path / "shape.h5"
    shutil.copy(shard_file, broken)
    with h5py.File(broken, "a") as f:
        del f["velocities"]
        f["velocities"] = np.zeros((3, 6, 94, 3), np.float32)
    with pytest.raises(DatasetError, match="shape.h5.*'velocities'.*N=96"):
        validate(broken)


def test_float64_positions_are_refused_by_name(shard_file, tmp_path):
    """A shard written by other code in float64 (it used to fail deep in training with "mat1 and
    mat2 must have the same dtype")."""
    wide = tmp_path / "wide.h5"
    shutil.copy(shard_file, wide)
    with h5py.File(wide, "a") as f:
        positions = f["positions"][()]
        del f["positions"]
        f["positions"] = positions.astype(np.float64)
    with pytest.raises(DatasetError, match=r"wide.h5: dataset 'positions' has dtype float64, expected float32"):
        validate(wide)


def test_missing_file_is_named(tmp_path):
    with pytest.raises(DatasetError, match="nope.h5: no such dataset file"):
        validate(tmp_path / "nope.h5")


def _nan_shard(tmp_path, key="positions", rollout=1):
    """A valid shard file written by the engine, then one value of ``key`` in ``rollout`` set to NaN in place."""
    generate(config(tmp_path))
    path = sorted((tmp_path / "rigid_fall/train").glob("shard_*.h5"))[0]
    with h5py.File(path, "r+") as f:
        data = f[key][()]
        data[rollout].flat[0] = float("nan")
        f[key][...] = data
        ids = f["rollout_ids"][()]
    return path, int(ids[rollout])


def test_a_shard_with_nan_is_refused_by_name_when_read_and_never_counted_as_generated(tmp_path):
    path, rollout = _nan_shard(tmp_path)
    with pytest.raises(DatasetError, match=rf"{path.name}: 'positions' holds NaN or inf in rollout\(s\) \[{rollout}\]"):
        read_shard(path, images=False)
    with h5py.File(path, "r") as f:
        config_hash = str(f.attrs["config_hash"])
    with pytest.raises(DatasetError, match="holds NaN"):
        shard_is_complete(path, config_hash)  # a rerun of task=generate stops on it instead of skipping it


def test_writing_refuses_non_finite_values_and_parameters_outside_their_range(tmp_path):
    path, _ = _nan_shard(tmp_path, "params", 0)
    good = sorted((tmp_path / "rigid_fall/test").glob("shard_*.h5"))[0]
    shard = read_shard(good, images=False)
    shard.velocities[0].flat[3] = float("inf")
    with pytest.raises(DatasetError, match=r"out\.h5: 'velocities' holds NaN or inf"):
        write_shard(tmp_path / "out.h5", shard)
    assert not (tmp_path / "out.h5").exists() and not list(tmp_path.glob("out.h5*.tmp"))
    shard = read_shard(good, images=False)
    shard.params[0, 0] = 3.0  # gravity is in [-15, -5]
    with pytest.raises(DatasetError, match=r"'params' of rollout\(s\) .* lie outside the range"):
        write_shard(tmp_path / "out.h5", shard)


def test_a_stray_copy_of_a_shard_is_refused_naming_both_files(tmp_path):
    generate(config(tmp_path))
    first = sorted((tmp_path / "rigid_fall/train").glob("shard_*.h5"))[0]
    shutil.copy(first, first.with_name("shard_00007.h5"))
    with pytest.raises(DatasetError, match=r"shard_00007\.h5: rollout \d+ is also in .*shard_00000\.h5"):
        load_split(tmp_path, "rigid_fall", "train")


def test_a_failed_write_leaves_no_temporary_file_and_writers_never_share_one(tmp_path):
    """Each write goes through a temporary file of its own (pid and a random part), removed when
    the write fails after it was made: a full disk at the rename leaves nothing behind."""
    from vgpl.atomic_write import temporary_path

    scene = make_scene("mass_rope", n_steps=4)
    plan = plan_shards(2, 1.0, 2)[0]
    shard = simulate_shard(scene, plan, seed=0, batch_size=2, render=False, device="cpu")
    shard.attrs = {**scene_attrs(scene, 0), "split": "train", "shard": 0, "config_hash": "abc"}

    def full_disk(tmp, path):
        assert tmp.exists() and tmp.name.startswith("out.h5.") and tmp.suffix == ".tmp"
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError, match=r"the disk is full \(\d+ MB free\) while writing out.h5; its temporary file was removed"):
        write_shard(tmp_path / "out.h5", shard, place=full_disk)
    assert list(tmp_path.iterdir()) == []
    names = {temporary_path(tmp_path / "out.h5").name for _ in range(20)}
    assert len(names) == 20 and all(n.startswith(f"out.h5.{os.getpid()}-") for n in names)


def test_a_second_writer_of_the_same_shard_between_anothers_write_and_rename_leaves_it_whole(tmp_path):
    """Writer A has written its temporary file; before A renames it, writer B writes and places the
    same shard. With one shared temporary name B would truncate A's file (or A would find none);
    with their own names both place a whole shard."""
    scene = make_scene("mass_rope", n_steps=4)
    shard = simulate_shard(scene, plan_shards(2, 1.0, 2)[0], seed=0, batch_size=2, render=False, device="cpu")
    shard.attrs = {**scene_attrs(scene, 0), "split": "train", "shard": 0, "config_hash": "abc"}
    target = tmp_path / "shard_00000.h5"

    def place_after_another_writer(tmp, path):
        write_shard(path, shard)  # writer B, start to finish
        os.replace(tmp, path)  # then writer A's rename

    write_shard(target, shard, place=place_after_another_writer)
    alone = write_shard(tmp_path / "alone.h5", shard)
    assert target.read_bytes() == alone.read_bytes() and read_shard(target, images=False).positions.shape == (2, 4, 96, 3)
    assert not list(tmp_path.glob("*.tmp"))
