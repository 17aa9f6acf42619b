"""Preview of a rollout: ground-truth particles and rendered frames side by side, as GIF or PNG."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from vgpl.data.shard import Shard
from vgpl.sim.camera import Camera
from vgpl.sim.renderer import SplatRenderer

PALETTE = np.array([[0.85, 0.25, 0.2], [0.2, 0.45, 0.9], [0.25, 0.7, 0.3], [0.95, 0.6, 0.15], [0.6, 0.3, 0.8]], dtype=np.float32)


def particle_frames(camera: Camera, instance: np.ndarray, positions: torch.Tensor, radius: float = 0.012, floor_y: float | None = None) -> np.ndarray:
    """Frames [T, H, W, 3] uint8 of particle positions [T, N, 3] as dots coloured by instance."""
    instance = np.asarray(instance)
    dots = SplatRenderer(camera, PALETTE[instance % len(PALETTE)], np.full(len(instance), radius), floor_y=floor_y)
    return dots.render(torch.as_tensor(positions).float()).numpy()


def preview_frames(shard: Shard, rollout: int = 0, scale: int = 2) -> np.ndarray:
    """[T, H*scale, 2*W*scale, 3] uint8: left, the ground-truth particles as small dots coloured by
    instance (drawn from the stored positions with the stored camera); right, the rendered video."""
    camera = Camera.from_json(str(shard.attrs["camera"]))
    left = particle_frames(camera, shard.instance, shard.positions[rollout])
    right = shard.images[rollout] if shard.images is not None else np.zeros_like(left)
    both = np.concatenate([left, right], axis=2)
    return both.repeat(scale, axis=1).repeat(scale, axis=2)


def gif_bytes(frames: np.ndarray, fps: int = 30) -> bytes:
    """Encode frames [T, H, W, 3] uint8 as an animated GIF."""
    images = [Image.fromarray(f) for f in frames]
    buffer = io.BytesIO()
    images[0].save(buffer, format="GIF", save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
    return buffer.getvalue()


def write_gif(frames: np.ndarray, path: str | Path, fps: int = 30) -> Path:
    """Write frames [T, H, W, 3] uint8 to an animated GIF."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(gif_bytes(frames, fps))
    return path


def write_png(frame: np.ndarray, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(frame).save(path)
    return path
