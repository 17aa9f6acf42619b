from __future__ import annotations

import numpy as np
import torch

from vgpl.sim.camera import Camera
from vgpl.sim.envs import make_scene
from vgpl.sim.renderer import SplatRenderer

CAM = Camera(eye=(0.0, 0.0, 2.0), target=(0.0, 0.0, 0.0), fov_y=45.0)


def test_projection_of_known_points():
    uvz = CAM.project(torch.tensor([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0]]))
    f = CAM.intrinsics[0, 0]
    assert torch.allclose(uvz[0], torch.tensor([80.0, 60.0, 2.0]), atol=1e-4)  # image centre
    assert abs(float(uvz[1, 0]) - (80 + f * 0.05)) < 1e-3  # +x world goes right
    assert float(uvz[2, 1]) < 60.0  # +y world (up) goes up in the image (smaller v)


def test_camera_json_round_trip():
    cam = Camera.from_json(CAM.to_json())
    assert cam == CAM
    assert np.allclose(cam.world_to_camera, CAM.world_to_camera)


def test_nearer_particle_wins_and_colours_are_kept():
    colors = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    r = SplatRenderer(CAM, colors, np.array([0.05, 0.05]), floor_y=None)
    near_red = torch.tensor([[[0.0, 0.0, 0.1], [0.0, 0.0, -0.1]]])
    near_blue = torch.tensor([[[0.0, 0.0, -0.1], [0.0, 0.0, 0.1]]])
    a, b = r.render(torch.cat([near_red, near_blue])).numpy()[:, 60, 80].astype(int)
    assert a[0] > 3 * a[2]  # red in front
    assert b[2] > 3 * b[0]  # blue in front


def test_background_where_no_particle_and_disc_size():
    r = SplatRenderer(CAM, np.array([[1.0, 0.0, 0.0]]), np.array([0.1]), floor_y=None)
    img = r.render(torch.zeros(1, 1, 3)).numpy()[0]
    red = img[..., 0].astype(int) > img[..., 1].astype(int) + 40  # shaded red, rim included
    expected_radius_px = CAM.intrinsics[0, 0] * 0.1 / 2.0
    assert abs(red.sum() - np.pi * expected_radius_px**2) / (np.pi * expected_radius_px**2) < 0.1
    assert not red[0, 0]


def test_instances_are_told_apart_by_colour():
    scene = make_scene("fluid_cube", n_steps=2)
    sample = scene.sample(np.random.default_rng(0))
    img = scene.renderer().render(torch.as_tensor(sample.positions)[None]).numpy()[0].reshape(-1, 3).astype(int)
    orange = ((img[:, 0] > 150) & (img[:, 2] < 90)).sum()  # cube
    blue = ((img[:, 2] > 120) & (img[:, 0] < 90)).sum()  # fluid
    assert orange > 50 and blue > 300
