"""Grounder's input checks and task=ground's video reading, on small untrained modules (the
trained pipeline's grounding, equal to task=evaluate's, is tests/tasks/test_pipeline.py)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

import vgpl
from tests.conftest import simulate
from tests.models.inference_options import inference_module
from vgpl.data.video_file import VideoFileError, read_actions, read_video
from vgpl.grounder import Grounder, GroundingInputError
from vgpl.models.dynamics_prior import DynamicsPrior
from vgpl.models.visual_prior import VisualPrior
from vgpl.sim.envs import make_scene


def small_grounder(env: str, observed: int = 6) -> Grounder:
    scene = make_scene(env, n_steps=16)
    low, high = scene.param_low.tolist(), scene.param_high.tolist()
    torch.manual_seed(0)
    dynamics = DynamicsPrior(low, high, scene.n_instances, 0.08, width=8)
    visual = VisualPrior(scene.n_particles, scene.n_instances, channels=[4, 4, 4, 4], hidden=16)
    inference = inference_module(low, high, scene.n_particles, scene.n_instances, 0.08, width=8, max_neighbors=8)
    return Grounder(visual, inference, dynamics, scene, observed=observed)


def test_vgpl_grounder_is_the_grounder():
    assert vgpl.Grounder is Grounder


def test_a_video_is_grounded_from_its_frames_into_every_estimate():
    """Shapes and units of every output, from frames alone (untrained modules: the values are not the point)."""
    grounder = small_grounder("rigid_fall")
    scene, (traj) = grounder.scene, simulate("rigid_fall", n_steps=16)[1]
    frames = scene.renderer().render(traj.positions[0]).numpy()
    g = grounder.ground(frames, n_future=5)
    n, m = scene.n_particles, scene.n_instances
    assert g.positions.shape == (6, n, 3) and g.proposals.shape == (6, n, 3) and g.future.shape == (5, n, 3)
    assert g.grouping.shape == (n, m) and torch.allclose(g.grouping.sum(-1), torch.ones(n))
    assert g.rigidness.shape == (m,) and bool(((g.rigidness > 0) & (g.rigidness < 1)).all())
    assert set(g.params) == {"gravity"} and -15.0 <= g.params["gravity"] <= -5.0  # tanh-bounded to the range, in m/s^2
    record = g.to_json()
    assert record["observed"] == 6 and record["n_future"] == 5 and len(record["instance"]) == n
    assert np.array(record["future"]).shape == (5, n, 3)


@pytest.mark.parametrize("frames, message", [
    (np.zeros((16, 60, 80, 3), np.uint8), r"frames: uint8 \[16, 60, 80, 3\], expected uint8 \[T >= 6, 120, 160, 3\]"),
    (np.zeros((16, 120, 160, 3), np.float32), r"frames: float32 \[16, 120, 160, 3\], expected uint8"),
    (np.zeros((5, 120, 160, 3), np.uint8), r"frames: 5 frames, expected at least 6 \(0 skipped \+ 6 observed\)"),
])
def test_frames_of_another_size_type_or_length_are_refused_saying_what_was_expected(frames, message):
    with pytest.raises(GroundingInputError, match=message):
        small_grounder("rigid_fall").ground(frames, n_future=5)


def test_an_actuated_scene_needs_its_actions_and_a_still_one_refuses_them():
    rope = small_grounder("mass_rope")
    frames = np.zeros((16, 120, 160, 3), np.uint8)
    with pytest.raises(GroundingInputError, match=r"actions: missing; mass_rope is driven by an actuator: expected \[11, 6\]"):
        rope.ground(frames, n_future=5)
    with pytest.raises(GroundingInputError, match=r"actions: \[8, 6\], expected \[>= 11, 6\]"):
        rope.ground(frames, np.zeros((8, 6)), n_future=5)
    with pytest.raises(GroundingInputError, match="actions: given, but rigid_fall has no actuator"):
        small_grounder("rigid_fall").ground(frames, np.zeros((16, 6)), n_future=5)


def test_the_actuated_particles_follow_the_actions_given():
    """MassRope's pin is where the actions put it, in the refined frames and the future: the
    engine's own placement (Scene.kinematic_positions), no ground truth read."""
    grounder = small_grounder("mass_rope")
    scene, traj = grounder.scene, simulate("mass_rope", n_steps=16)[1]
    frames = scene.renderer().render(traj.positions[0]).numpy()
    g = grounder.ground(frames, traj.actions[0].numpy(), n_future=5)
    pin = torch.as_tensor(scene.kinematic)
    assert torch.equal(g.positions[:, pin], traj.positions[0, :6, pin])
    assert torch.equal(g.future[:, pin], traj.positions[0, 6:11, pin])


def test_video_files_and_png_folders_are_read_as_rgb_frames(tmp_path):
    frames = np.zeros((4, 120, 160, 3), np.uint8)
    frames[:, :, :80, 0] = 200  # red left half: RGB order is kept
    frames[np.arange(4), 10 * np.arange(4)] = 255  # a white row moving down
    for k, f in enumerate(frames):
        cv2.imwrite(str(tmp_path / f"frame_{k:03d}.png"), cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    read, actions = read_video(tmp_path)
    assert actions is None and np.array_equal(read, frames)  # PNG is lossless
    writer = cv2.VideoWriter(str(tmp_path / "v.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 10, (160, 120))
    for f in frames:
        writer.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    writer.release()
    video, _ = read_video(tmp_path / "v.mp4")
    assert video.shape == frames.shape and np.abs(video.astype(int) - frames).mean() < 8  # lossy, but these frames
    assert video[0, 60, 20, 0] > 150 and video[0, 60, 140, 0] < 50


def test_a_non_hdf5_h5_file_is_named_as_a_video_input(tmp_path):
    from vgpl.data.video_file import read_video

    (tmp_path / "clip.h5").write_bytes(b"not an HDF5 file")
    with pytest.raises(VideoFileError, match=r"clip.h5: not a readable HDF5 file \(.*\); task.video takes a dataset shard .h5"):
        read_video(tmp_path / "clip.h5")


def test_png_frames_are_read_in_natural_order_and_must_be_rgb(tmp_path):
    """frame_0.png ... frame_11.png, as ffmpeg's %d.png names them: 2 before 10, not after 1."""
    frames = np.zeros((12, 8, 8, 3), np.uint8)
    frames[:, 0, 0, 0] = np.arange(12) * 20  # each frame says which it is
    for k, f in enumerate(frames):
        cv2.imwrite(str(tmp_path / f"frame_{k}.png"), cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    read, _ = read_video(tmp_path)
    assert read[:, 0, 0, 0].tolist() == (np.arange(12) * 20).tolist()
    gray = tmp_path / "gray"
    gray.mkdir()
    cv2.imwrite(str(gray / "0.png"), np.zeros((8, 8), np.uint8))
    with pytest.raises(VideoFileError, match=r"gray/0.png: a grayscale uint8 PNG, expected RGB \(or RGBA\) with 8 bits per channel"):
        read_video(gray)
    deep = tmp_path / "deep"
    deep.mkdir()
    cv2.imwrite(str(deep / "0.png"), np.zeros((8, 8, 3), np.uint16))
    with pytest.raises(VideoFileError, match="deep/0.png: a 3-channel uint16 PNG, expected RGB"):
        read_video(deep)


def test_unreadable_videos_and_actions_are_named(tmp_path):
    with pytest.raises(VideoFileError, match="nope.mp4: no such video"):
        read_video(tmp_path / "nope.mp4")
    (tmp_path / "clip.gif").write_bytes(b"GIF89a")
    with pytest.raises(VideoFileError, match="clip.gif: a .gif file, expected one of .mp4"):
        read_video(tmp_path / "clip.gif")
    (tmp_path / "broken.mp4").write_bytes(b"not a video")
    with pytest.raises(VideoFileError, match="broken.mp4: no frame could be decoded"):
        read_video(tmp_path / "broken.mp4")
    (tmp_path / "empty").mkdir()
    with pytest.raises(VideoFileError, match="empty: no \\*.png frames"):
        read_video(tmp_path / "empty")
    np.save(tmp_path / "a.npy", np.zeros(5))
    with pytest.raises(VideoFileError, match=r"a.npy: actions of shape \[5\], expected \[T, A\]"):
        read_actions(tmp_path / "a.npy")


def test_a_test_time_fit_moves_the_estimate_towards_the_videos_own_frames():
    """With steps > 0 the grounder's P differs from the amortised one (untrained modules: the
    direction is not the point; tests/eval/test_test_time_fit.py checks it finds the truth)."""
    from vgpl.eval.test_time_fit import TestTimeFit

    grounder = small_grounder("rigid_fall")
    frames = grounder.scene.renderer().render(simulate("rigid_fall", n_steps=16)[1].positions[0]).numpy()
    amortised = grounder.ground(frames, n_future=3)
    fitted = grounder.ground(frames, n_future=3, test_time_fit=TestTimeFit(steps=5, lr=0.5))
    assert fitted.params["gravity"] != pytest.approx(amortised.params["gravity"], abs=1e-3)
    assert torch.equal(fitted.positions, amortised.positions)  # only P and Q are fitted


def test_a_checkpoint_folder_of_mixed_envs_names_each_stages_env(tmp_path):
    """A folder whose prior is of another env than its visual prior and module: one error listing
    each stage's env (it used to blame the good visual/ and suggest an env= the Python API lacks)."""
    from omegaconf import OmegaConf

    from vgpl.grounder import Grounder

    classes = {"dynamics": "vgpl.models.dynamics_prior.DynamicsPrior", "visual": "vgpl.models.visual_prior.VisualPrior",
               "inference": "vgpl.models.inference.InferenceModule"}
    for stage, cls in classes.items():
        (tmp_path / stage).mkdir()
        (tmp_path / stage / "last.ckpt").write_bytes(b"")  # never loaded: the envs are compared first
        OmegaConf.save({"env": {"name": "rigid_fall" if stage == "dynamics" else "mass_rope"}, "stage_class": cls}, tmp_path / stage / "config.yaml")
    with pytest.raises(GroundingInputError, match=r"its stages were trained on different envs \(.*dynamics/last.ckpt on 'rigid_fall', "
                                                  r".*visual/last.ckpt on 'mass_rope', .*inference/last.ckpt on 'mass_rope'\)"):
        Grounder.from_checkpoints(tmp_path)
