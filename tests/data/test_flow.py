from __future__ import annotations

import numpy as np
import torch

from vgpl.data.flow import farneback_flow, flow_error, particle_flow
from vgpl.eval.linear_probe import Ridge
from vgpl.sim.camera import Camera
from vgpl.sim.envs import make_scene


def test_particle_flow_is_the_projected_motion_and_zero_on_the_background():
    cam = Camera(eye=(0.0, 0.5, 2.0), target=(0.0, 0.5, 0.0))
    a = torch.tensor([[0.0, 0.5, 0.0], [0.3, 0.4, 0.0]])
    b = a + torch.tensor([[0.02, 0.0, 0.0], [0.0, -0.03, 0.0]])
    flow = particle_flow(cam, torch.stack([a, b]))  # [1, H, W, 2]
    uv_a, uv_b = cam.project(a)[:, :2], cam.project(b)[:, :2]
    for p in range(2):
        u, v = uv_a[p].floor().long().tolist()
        assert torch.allclose(flow[0, v, u], uv_b[p] - uv_a[p])
    moving = flow.norm(dim=-1) > 0
    assert moving.sum() == 2 * 9  # a 3x3 splat per particle, nothing else moves


def test_ridge_recovers_a_linear_map():
    torch.manual_seed(0)
    x = torch.randn(200, 6)
    y = x @ torch.tensor([[1.0], [-2.0], [0.0], [0.5], [0.0], [3.0]]) + 4.0
    ridge = Ridge.fit(x, y, alpha=1e-6)
    assert torch.allclose(ridge.predict(x), y, atol=1e-3)


def test_farneback_flow_from_rendered_frames_follows_the_simulators_flow():
    """Flow estimated from the rendered RigidFall frames (the paper's kind of input) is closer to the
    simulator's flow than predicting no motion, on the pixels the simulator moves; the same error of
    the simulator's own flow is zero."""
    scene = make_scene("rigid_fall", n_steps=14)
    traj = scene.simulate([scene.sample(np.random.default_rng(0))])
    frames = scene.renderer().render(traj.positions[0, 8:13])  # falling cubes
    simulated = particle_flow(scene.camera, traj.positions[0, 8:13])
    estimated = farneback_flow(frames)
    assert estimated.shape == simulated.shape == (4, scene.camera.height, scene.camera.width, 2)
    error = flow_error(estimated, simulated)
    assert error["epe"] < 0.6 * error["epe_zero"] and error["epe_zero"] > 0.5  # the cubes move half a pixel a frame or more
    assert flow_error(simulated, simulated)["epe"] == 0.0


def test_evaluation_windows_of_estimated_flow_carry_the_simulators_flow_to_measure_it_by(tmp_path):
    """FlowWindows(flow="farneback", reference=True): each item's flow is Farneback's from its frames
    and ``simulator_flow`` the particles' own; training windows (reference off) and windows of the
    simulator's flow carry no second flow."""
    from hydra import compose, initialize_config_dir

    from tests.conftest import REPO
    from vgpl.data.flow_windows import FlowWindows
    from vgpl.data.trajectories import load_split
    from vgpl.tasks.generate import generate

    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        generate(compose("config", overrides=["task=generate", "env=rigid_fall", "env.scene.n_steps=12", f"data.root={tmp_path}",
                                              "data.n_rollouts=2", "data.train_fraction=0.5", "data.progress=false"]))
    videos = load_split(tmp_path, "rigid_fall", "test", images=True)
    scene = make_scene("rigid_fall")
    item = FlowWindows(videos, scene.camera, 4, flow="farneback", reference=True)[0]
    torch.testing.assert_close(item["flow"], farneback_flow(videos.images[0, :5]))
    torch.testing.assert_close(item["simulator_flow"], particle_flow(scene.camera, videos.positions[0, :5]))
    assert "simulator_flow" not in FlowWindows(videos, scene.camera, 4, flow="farneback")[0]
    assert "simulator_flow" not in FlowWindows(videos, scene.camera, 4, flow="simulator", reference=True)[0]


def test_estimated_flow_is_computed_once_per_split_and_every_window_reads_the_estimators_numbers(tmp_path, monkeypatch):
    """The flow cache next to the shards: windows read Farneback's flow of their frames (to float16's
    precision), a second request with fewer videos or frame pairs reads the same file without
    estimating again, and a request for more frame pairs rebuilds it."""
    from hydra import compose, initialize_config_dir

    import vgpl.data.flow_cache as cache
    from tests.conftest import REPO
    from vgpl.data.flow_cache import CachedFlow, ensure_flow_cache
    from vgpl.data.flow_windows import FlowWindows
    from vgpl.data.trajectories import load_split
    from vgpl.tasks.generate import generate

    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        generate(compose("config", overrides=["task=generate", "env=rigid_fall", "env.scene.n_steps=14", f"data.root={tmp_path}",
                                              "data.n_rollouts=3", "data.train_fraction=1.0", "data.progress=false"]))
    videos = load_split(tmp_path, "rigid_fall", "train", images=True)
    scene = make_scene("rigid_fall")
    windows = FlowWindows(videos, scene.camera, 4, stride=3, flow="farneback")
    assert windows.pairs_needed == 9 + 4  # the last window starts at frame 9
    path = ensure_flow_cache(tmp_path, "rigid_fall", "train", videos, 8)
    assert path == tmp_path / "rigid_fall/flow/train.h5"
    calls = []
    monkeypatch.setattr(cache, "farneback_flow", lambda frames: calls.append(1) or farneback_flow(frames))
    first_two = load_split(tmp_path, "rigid_fall", "train", images=True, max_rollouts=2)
    assert ensure_flow_cache(tmp_path, "rigid_fall", "train", first_two, 4) == path and not calls  # read, not estimated
    ensure_flow_cache(tmp_path, "rigid_fall", "train", videos, windows.pairs_needed)
    assert len(calls) == 3  # more pairs than it held: estimated again, once per video
    windows.cache = CachedFlow(path)
    for k in (0, len(windows) - 1):
        r, s = windows.index[k]
        torch.testing.assert_close(windows[k]["flow"], farneback_flow(videos.images[r, s : s + 5]), atol=4e-3, rtol=2e-3)
