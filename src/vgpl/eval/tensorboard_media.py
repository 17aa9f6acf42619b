"""TensorBoard media without extra encoders: rollout videos as animated GIF image summaries
(what ``SummaryWriter.add_video`` writes, minus its moviepy dependency)."""

from __future__ import annotations

import numpy as np
import torch
from tensorboard.compat.proto.summary_pb2 import Summary

from vgpl.eval.preview import gif_bytes, particle_frames
from vgpl.sim.camera import Camera


def add_gif(writer, tag: str, frames: np.ndarray, step: int, fps: int = 15) -> None:
    """Log frames [T, H, W, 3] uint8 to a ``torch.utils.tensorboard.SummaryWriter`` as a video."""
    t, h, w, c = frames.shape
    image = Summary.Image(height=h, width=w, colorspace=c, encoded_image_string=gif_bytes(frames, fps))
    writer._get_file_writer().add_summary(Summary(value=[Summary.Value(tag=tag, image=image)]), step)


def rollout_video(camera: Camera, instance: np.ndarray, truth: torch.Tensor, pred: torch.Tensor) -> np.ndarray:
    """Frames [T, H, 2W, 3]: ground truth (left) and prediction (right) of one rollout [T, N, 3],
    particles drawn from the dataset's camera and coloured by instance."""
    draw = lambda x: particle_frames(camera, instance, x, radius=0.025, floor_y=0.0)  # noqa: E731
    return np.concatenate([draw(truth), draw(pred)], axis=2)
