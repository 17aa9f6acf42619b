"""The reader of the authors' FleX rollouts, on small synthetic files in their two layouts: one
HDF5 file per frame (<rollout>/<frame>.h5) and one packed file with a group per rollout."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from vgpl.data.flex_rollouts import FlexFormatError, as_rollouts, read_flex_rollouts
from vgpl.sim.envs import make_scene


def _rollout(rng, frames: int, rows: int, params: np.ndarray) -> dict:
    return {"positions": rng.normal(size=(frames, rows, 3)).astype(np.float32),
            "shape_quats": np.zeros((frames, 1, 4), np.float32), "scene_params": params}


def _write_frames(root, name: str, rollout: dict, velocities: bool = False) -> None:
    folder = root / name
    folder.mkdir(parents=True)
    for t in range(rollout["positions"].shape[0]):  # as the authors' store_data writes each frame
        with h5py.File(folder / f"{t}.h5", "w") as f:
            f["positions"] = rollout["positions"][t]
            f["shape_quats"] = rollout["shape_quats"][t]
            f["scene_params"] = rollout["scene_params"]
            if velocities:
                f["velocities"] = rollout["positions"][t] * 2


def _rigid_fall_params(gravity: float) -> np.ndarray:
    return np.array([3, gravity, 0.01, 0.09, 0.02, 0.03, 0.30, 0.04, 0.05, 0.51, 0.06, 1.0])


def test_per_frame_and_packed_layouts_read_the_same_rollouts(tmp_path):
    rng = np.random.default_rng(0)
    rollouts = {name: _rollout(rng, 12, 193, _rigid_fall_params(g)) for name, g in (("0", -7.5), ("1", -12.0), ("10", -5.5))}
    for name, r in rollouts.items():
        _write_frames(tmp_path / "demo", name, r, velocities=True)
    with h5py.File(tmp_path / "packed.h5", "w") as f:
        for name, r in rollouts.items():
            f[f"{name}/positions"] = r["positions"]
            f[f"{name}/velocities"] = r["positions"] * 2
            f[f"{name}/scene_params"] = r["scene_params"]
        f["stat/positions"] = np.zeros((3, 3))  # the authors' normalisation statistics: not a rollout
    for read in (read_flex_rollouts(tmp_path / "demo", "rigid_fall"), read_flex_rollouts(tmp_path / "packed.h5", "rigid_fall")):
        assert [r.name for r in read] == ["0", "1", "10"]  # numbers as numbers
        for r in read:
            truth = rollouts[r.name]
            np.testing.assert_array_equal(r.positions, truth["positions"][:, :192])  # frames 0..11 in order (2 before 10), floor row dropped
            np.testing.assert_array_equal(r.velocities, truth["positions"][:, :192] * 2)
            assert r.params.tolist() == [np.float32(truth["scene_params"][1])]  # gravity
        assert np.bincount(read[0].instance).tolist() == [64, 64, 64] and read[0].rigid.tolist() == [True] * 3 and read[0].pin is None
    one = read_flex_rollouts(tmp_path / "demo" / "1", "rigid_fall")  # a single rollout's folder
    assert len(one) == 1 and one[0].params[0] == np.float32(-12.0)


def test_mass_ropes_pin_row_is_shifted_to_the_frame_it_belongs_to(tmp_path):
    rng = np.random.default_rng(1)
    r = _rollout(rng, 5, 96, np.array([0.0, 1.0, 0.0, 0.7, 0.8, 1.0]))
    _write_frames(tmp_path, "0", r)
    [read] = read_flex_rollouts(tmp_path, "mass_rope")
    stored = r["positions"][:, 95]  # row 95 of frame t: the pin at frame t + 1
    np.testing.assert_array_equal(read.pin[1:], stored[:-1])
    np.testing.assert_array_equal(read.positions[1:, 95], stored[:-1])
    # frame 0's pin: where FleX creates it, above the rope's last particle at the pin's height
    np.testing.assert_array_equal(read.pin[0], [r["positions"][0, 94, 0], stored[0, 1], r["positions"][0, 94, 2]])
    np.testing.assert_array_equal(read.positions[:, :95], r["positions"][:, :95])
    assert read.positions.shape == (5, 96, 3) and read.params.tolist() == [np.float32(0.8)] and read.velocities is None
    assert np.bincount(read.instance).tolist() == [81, 15] and read.rigid.tolist() == [True, False]


def test_files_of_another_layout_are_refused_naming_the_file(tmp_path):
    rng = np.random.default_rng(2)
    _write_frames(tmp_path / "rope", "0", _rollout(rng, 3, 96, np.zeros(6)))
    with pytest.raises(FlexFormatError, match=r"rope/0: 'positions' has shape \(3, 96, 3\), expected \[T, 193, 3\] for rigid_fall"):
        read_flex_rollouts(tmp_path / "rope", "rigid_fall")
    (tmp_path / "junk.h5").write_bytes(b"not hdf5")
    with pytest.raises(FlexFormatError, match="junk.h5: not a readable HDF5 file"):
        read_flex_rollouts(tmp_path / "junk.h5", "rigid_fall")
    with h5py.File(tmp_path / "no_params.h5", "w") as f:
        f["0/positions"] = np.zeros((2, 193, 3), np.float32)
    with pytest.raises(FlexFormatError, match=r"no_params.h5:/0: no 'scene_params'"):
        read_flex_rollouts(tmp_path / "no_params.h5", "rigid_fall")
    (tmp_path / "frames").mkdir()
    (tmp_path / "frames" / "last.h5").write_bytes(b"")
    with pytest.raises(FlexFormatError, match="frame files must be named <frame>.h5 with a number, found last.h5"):
        read_flex_rollouts(tmp_path / "frames", "rigid_fall")
    with pytest.raises(ValueError, match="env 'fluid_cube': the authors released FleX rollouts of"):
        read_flex_rollouts(tmp_path / "rope", "fluid_cube")
    with pytest.raises(FileNotFoundError, match="nowhere: no such file or folder"):
        read_flex_rollouts(tmp_path / "nowhere", "rigid_fall")


def test_flex_rollouts_become_a_test_split_with_the_pins_path_as_actions(tmp_path):
    rng = np.random.default_rng(3)
    _write_frames(tmp_path / "fall", "0", _rollout(rng, 4, 193, _rigid_fall_params(-9.0)))
    _write_frames(tmp_path / "fall", "1", _rollout(rng, 4, 193, _rigid_fall_params(-6.0)))
    read = read_flex_rollouts(tmp_path / "fall", "rigid_fall")
    split = as_rollouts(read, make_scene("rigid_fall"))
    assert split.positions.shape == (2, 4, 192, 3) and split.params[:, 0].tolist() == [-9.0, -6.0]
    assert split.actions.shape == (2, 4, 0) and split.param_low.tolist() == [-15.0] and split.env == "rigid_fall"
    np.testing.assert_array_equal(split.positions[1].numpy(), read[1].positions)
    _write_frames(tmp_path / "rope", "0", _rollout(rng, 4, 96, np.array([0.0, 1.0, 0.0, 0.7, 0.5, 1.0])))
    rope = read_flex_rollouts(tmp_path / "rope", "mass_rope")
    split = as_rollouts(rope, make_scene("mass_rope"))
    assert split.positions.shape == (1, 4, 96, 3) and split.actions.shape == (1, 4, 6) and split.params.tolist() == [[0.5]]
    np.testing.assert_allclose(split.actions[0, :, :3].numpy(), rope[0].pin)
    np.testing.assert_allclose(split.actions[0, 1:, 3:].numpy(), np.diff(rope[0].pin, axis=0) * 60, rtol=1e-4)  # m/s at 60 frames/s
    assert not split.actions[0, 0, 3:].any()
    with pytest.raises(ValueError, match=r"FleX rollouts of \['mass_rope'\] given as the test split of env 'rigid_fall'"):
        as_rollouts(rope, make_scene("rigid_fall"))
