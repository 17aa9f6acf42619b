"""Optical flow for the DensePhysNet baseline: the simulator's (each particle's pixel motion
splatted into a flow image: privileged, noise-free) or estimated from the rendered frames
(OpenCV's Farneback; the paper used Liu (2009), which vgpl does not carry), and how far the two are apart."""

from __future__ import annotations

import numpy as np
import torch

FARNEBACK = {"pyr_scale": 0.5, "levels": 3, "winsize": 9, "iterations": 3, "poly_n": 5, "poly_sigma": 1.1}  # farneback_flow's settings


def particle_flow(camera, positions: torch.Tensor, splat: int = 1) -> torch.Tensor:
    """Flow images [T - 1, H, W, 2] (pixels per frame, u right, v down) from positions [T, N, 3].

    Each particle writes its motion from frame t to t + 1 into the (2 splat + 1)^2 pixels around
    where it is at t; the nearest particle to the camera wins a pixel; pixels with no particle
    (static background) have zero flow.
    """
    t, n, _ = positions.shape
    h, w = camera.height, camera.width
    uvz = camera.project(positions.float())  # [T, N, 3]
    motion = uvz[1:, :, :2] - uvz[:-1, :, :2]  # [T-1, N, 2]
    flow = torch.zeros(t - 1, h * w, 2)
    depth = torch.full((t - 1, h * w), float("inf"))
    offs = torch.arange(-splat, splat + 1)
    dv, du = torch.meshgrid(offs, offs, indexing="ij")
    u = uvz[:-1, :, 0].floor().long()[..., None] + du.reshape(-1)  # [T-1, N, K]
    v = uvz[:-1, :, 1].floor().long()[..., None] + dv.reshape(-1)
    z = uvz[:-1, :, 2:3].expand_as(u)
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h) & (z > 0)
    frame = torch.arange(t - 1)[:, None, None].expand_as(u)
    pix = (v * w + u).clamp(0, h * w - 1)
    # nearest particle per pixel: scatter-min of depth, then write the flow of the winners
    depth.view(-1).scatter_reduce_(0, (frame * h * w + pix)[inside], z[inside], reduce="amin")
    winner = inside & (z <= depth.view(-1)[(frame * h * w + pix)].view_as(z))
    idx = (frame * h * w + pix)[winner]
    vals = motion[:, :, None, :].expand(-1, -1, u.shape[-1], -1)[winner]
    flow.view(-1, 2).index_put_((idx,), vals)
    return flow.view(t - 1, h, w, 2)


def farneback_flow(frames: torch.Tensor) -> torch.Tensor:
    """Classical optical flow (OpenCV's Farneback) between consecutive frames uint8 [T, H, W, 3]
    -> [T - 1, H, W, 2]; as the paper did with an estimator instead of simulator flow."""
    try:
        import cv2
    except ImportError as e:
        raise ImportError("model.densephysnet.flow=farneback needs OpenCV: pip install opencv-python-headless (or use flow=simulator)") from e
    gray = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in frames.numpy()]
    out = [cv2.calcOpticalFlowFarneback(a, b, None, **FARNEBACK, flags=0) for a, b in zip(gray[:-1], gray[1:])]
    return torch.as_tensor(np.stack(out))


def flow_error(estimated: torch.Tensor, simulated: torch.Tensor) -> dict[str, float]:
    """How far an estimated flow [..., H, W, 2] is from the simulator's [..., H, W, 2] (pixels per
    frame), on the pixels the simulator moves: the mean end-point error, and that of predicting no
    motion there (the error an estimator that sees nothing would have)."""
    moving = simulated.norm(dim=-1) > 0
    if not bool(moving.any()):
        raise ValueError("flow_error: the simulator's flow moves no pixel in these frames")
    return {"epe": float((estimated - simulated).norm(dim=-1)[moving].mean()), "epe_zero": float(simulated.norm(dim=-1)[moving].mean())}
