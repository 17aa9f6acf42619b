"""Batched software renderer: particles drawn as shaded sphere impostors with a z-buffer.

Pure PyTorch (same pictures on CPU and GPU, no display or GL context). Each particle covers a
small square window of pixels; pixels inside its projected disc get the depth of the sphere's
front surface; the nearest surface wins via ``scatter_reduce(amin)`` on keys that pack
(depth, particle id) into one int64; the winner is shaded with a Lambert term.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from vgpl.sim.camera import Camera

_ID_BITS = 20  # up to ~1M particles per scene
_DEPTH_SCALE = 2.0**20  # depth quantisation: 1e-6 m


class SplatRenderer:
    """Render particle positions [B, N, 3] into uint8 RGB frames [B, H, W, 3].

    Args:
        camera: the fixed camera.
        colors: [N, 3] float RGB in [0, 1] for each particle.
        radius: [N] drawn sphere radii (world units).
        floor_y: height of a checkered floor plane drawn in the background, or None.
    """

    def __init__(self, camera: Camera, colors: np.ndarray, radius: np.ndarray, floor_y: float | None = 0.0) -> None:
        self.near = 0.05  # metres: particles closer to the camera (or behind it) are not drawn
        self.camera = camera
        self.colors = torch.as_tensor(np.asarray(colors, dtype=np.float32))
        self.radius = torch.as_tensor(np.asarray(radius, dtype=np.float32))
        self.background = torch.as_tensor(self._background(floor_y))
        light = np.array([0.4, 0.8, 0.45])  # camera frame: travelling right, down and away (lit from the upper left)
        self.light = torch.as_tensor(light / np.linalg.norm(light), dtype=torch.float32)

    def _background(self, floor_y: float | None) -> np.ndarray:
        rays = self.camera.rays()
        sky = 0.75 + 0.2 * rays[..., 1:2].clip(-1, 1)
        img = np.broadcast_to(sky * np.array([0.85, 0.9, 1.0]), rays.shape).copy()
        if floor_y is not None:
            eye = np.asarray(self.camera.eye)
            t = (floor_y - eye[1]) / np.where(rays[..., 1] < -1e-6, rays[..., 1], -1e-6)
            hit = (rays[..., 1] < -1e-6) & (t > 0)
            pts = eye + t[..., None] * rays
            checker = (np.floor(pts[..., 0] / 0.25) + np.floor(pts[..., 2] / 0.25)) % 2
            floor = (0.55 + 0.1 * checker)[..., None] * np.array([1.0, 0.97, 0.9])
            fog = np.exp(-0.15 * np.where(hit, t, 0.0))[..., None]  # fade into the sky with distance
            img = np.where(hit[..., None], fog * floor + (1 - fog) * img, img)
        return img.astype(np.float32)

    @torch.no_grad()
    def render(self, positions: torch.Tensor, chunk: int = 64) -> torch.Tensor:
        """Frames [B, H, W, 3] uint8 for positions [B, N, 3] (processed ``chunk`` frames at a time)."""
        out = [self._render(positions[s : s + chunk]) for s in range(0, positions.shape[0], chunk)]
        return torch.cat(out) if out else torch.empty(0, self.camera.height, self.camera.width, 3, dtype=torch.uint8)

    def _render(self, positions: torch.Tensor) -> torch.Tensor:
        device = positions.device
        cam = self.camera
        h, w = cam.height, cam.width
        b, n, _ = positions.shape
        radius, colors = self.radius.to(device), self.colors.to(device)
        uvz = cam.project(positions.float())  # [B, N, 3]
        f = float(cam.intrinsics[0, 0])
        visible = torch.isfinite(uvz).all(-1) & (uvz[..., 2] > self.near)  # [B, N]; predictions may stray
        z = torch.where(visible, uvz[..., 2], torch.ones_like(uvz[..., 2]))
        rp = f * radius / z  # [B, N] pixel radius
        largest = float(rp[visible].max()) if visible.any() else 1.0
        half = min(max(1, math.ceil(largest)), max(h, w))
        offs = torch.arange(-half, half + 1, device=device)
        dy, dx = torch.meshgrid(offs, offs, indexing="ij")
        dy, dx = dy.reshape(-1), dx.reshape(-1)  # [K]
        pu = uvz[..., 0].floor().long()[..., None] + dx  # [B, N, K]
        pv = uvz[..., 1].floor().long()[..., None] + dy
        du = pu.float() + 0.5 - uvz[..., 0, None]
        dv = pv.float() + 0.5 - uvz[..., 1, None]
        q = (du * du + dv * dv) / (rp * rp)[..., None]  # squared normalised distance to the disc centre
        inside = (q < 1.0) & (pu >= 0) & (pu < w) & (pv >= 0) & (pv < h) & visible[..., None]
        depth = z[..., None] - radius[None, :, None] * torch.sqrt((1.0 - q).clamp_min(0.0))
        key = (depth * _DEPTH_SCALE).long() * (1 << _ID_BITS) + torch.arange(n, device=device)[None, :, None]
        pix = (torch.arange(b, device=device)[:, None, None] * h + pv) * w + pu
        empty = torch.iinfo(torch.long).max
        zbuf = torch.full((b * h * w,), empty, dtype=torch.long, device=device)
        zbuf.scatter_reduce_(0, pix[inside], key[inside], "amin")
        hit = zbuf != empty
        image = self.background.to(device).expand(b, h, w, 3).reshape(-1, 3).clone()
        if bool(hit.any()):
            pixel = hit.nonzero(as_tuple=True)[0]
            scene = pixel // (h * w)
            particle = zbuf[pixel] % (1 << _ID_BITS)
            py, px = (pixel % (h * w)) // w, pixel % w
            c = uvz[scene, particle]
            r = rp[scene, particle]
            nx, ny = (px.float() + 0.5 - c[:, 0]) / r, (py.float() + 0.5 - c[:, 1]) / r
            nz = -torch.sqrt((1.0 - nx * nx - ny * ny).clamp_min(0.0))
            lambert = (-(torch.stack([nx, ny, nz], -1) @ self.light.to(device))).clamp_min(0.0)
            image[pixel] = colors[particle] * (0.35 + 0.65 * lambert)[:, None]
        return (image.reshape(b, h, w, 3).clamp(0, 1) * 255.0 + 0.5).to(torch.uint8)
