"""Pinhole camera (OpenCV convention: x right, y down, z forward) with JSON round trip."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np
import torch


@dataclass(frozen=True)
class Camera:
    """A fixed camera looking from ``eye`` at ``target`` with vertical field of view ``fov_y`` (degrees)."""

    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    fov_y: float = 45.0
    width: int = 160
    height: int = 120

    @property
    def intrinsics(self) -> np.ndarray:
        """[3, 3] K matrix in pixels."""
        f = 0.5 * self.height / math.tan(math.radians(self.fov_y) / 2)
        return np.array([[f, 0.0, self.width / 2], [0.0, f, self.height / 2], [0.0, 0.0, 1.0]])

    @property
    def world_to_camera(self) -> np.ndarray:
        """[4, 4] extrinsic matrix [R | -R eye]."""
        eye, target = np.asarray(self.eye, float), np.asarray(self.target, float)
        forward = (target - eye) / np.linalg.norm(target - eye)
        right = np.cross(forward, [0.0, 1.0, 0.0])
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        rot = np.stack([right, down, forward])
        ext = np.eye(4)
        ext[:3, :3], ext[:3, 3] = rot, -rot @ eye
        return ext

    def to_camera(self, points: torch.Tensor) -> torch.Tensor:
        """World points [..., 3] to camera coordinates [..., 3]."""
        ext = torch.as_tensor(self.world_to_camera, dtype=points.dtype, device=points.device)
        return points @ ext[:3, :3].T + ext[:3, 3]

    def project(self, points: torch.Tensor) -> torch.Tensor:
        """World points [..., 3] to pixel coordinates (u, v) and depth z: [..., 3]."""
        cam = self.to_camera(points)
        k = torch.as_tensor(self.intrinsics, dtype=points.dtype, device=points.device)
        z = cam[..., 2:3]
        uv = cam[..., :2] / z * torch.stack([k[0, 0], k[1, 1]]) + torch.stack([k[0, 2], k[1, 2]])
        return torch.cat([uv, z], -1)

    def unproject(self, uv: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
        """Pixel coordinates [..., 2] at camera depths [...] to world points [..., 3] (``unproject``)."""
        return unproject(uv, depth, torch.as_tensor(self.intrinsics, dtype=uv.dtype, device=uv.device),
                         torch.as_tensor(self.world_to_camera, dtype=uv.dtype, device=uv.device))

    def rays(self) -> np.ndarray:
        """[H, W, 3] world-space unit ray directions through the pixel centres."""
        k_inv = np.linalg.inv(self.intrinsics)
        v, u = np.mgrid[0 : self.height, 0 : self.width] + 0.5
        d = np.stack([u, v, np.ones_like(u)], -1) @ k_inv.T @ self.world_to_camera[:3, :3]
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def to_json(self) -> str:
        return json.dumps(
            {
                "eye": list(self.eye),
                "target": list(self.target),
                "fov_y": self.fov_y,
                "width": self.width,
                "height": self.height,
                "intrinsics": self.intrinsics.tolist(),
                "world_to_camera": self.world_to_camera.tolist(),
                "convention": "opencv: x right, y down, z forward; pixel (u, v) = K (R x + t)",
            }
        )

    @classmethod
    def from_json(cls, text: str) -> Camera:
        d = json.loads(text)
        return cls(tuple(d["eye"]), tuple(d["target"]), d["fov_y"], d["width"], d["height"])


def unproject(uv: torch.Tensor, depth: torch.Tensor, intrinsics: torch.Tensor, world_to_camera: torch.Tensor) -> torch.Tensor:
    """World points [..., 3] of pixels ``uv`` [..., 2] at camera depths ``depth`` [...] (z forward),
    through K ``intrinsics`` [3, 3] and the extrinsic ``world_to_camera`` [4, 4]: the inverse of
    :meth:`Camera.project`."""
    x = (uv[..., 0] - intrinsics[0, 2]) / intrinsics[0, 0] * depth
    y = (uv[..., 1] - intrinsics[1, 2]) / intrinsics[1, 1] * depth
    cam = torch.stack([x, y, depth], -1)
    rot, t = world_to_camera[:3, :3], world_to_camera[:3, 3]
    return (cam - t) @ rot
