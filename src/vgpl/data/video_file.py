"""Reading one video for task=ground: a video file (MP4, AVI, ... through OpenCV), a folder of
PNG frames (in natural file-name order: frame_2 before frame_10), or one rollout of a dataset shard
(``.h5``, its frames and actions). Frames come back RGB uint8 [T, H, W, 3]; actions [T, A] or None."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import h5py
import numpy as np

from vgpl.data.shard import read_shard

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm")


class VideoFileError(ValueError):
    """A video that cannot be read, naming the file and what was expected."""


def read_video(path: str | Path, rollout: int = 0) -> tuple[np.ndarray, np.ndarray | None]:
    """(frames uint8 [T, H, W, 3] RGB, actions [T, A] or None) of ``path``: a shard's rollout
    ``rollout`` (its position in the file), a video file, or a folder of ``*.png``."""
    path = Path(path)
    if not path.exists():
        raise VideoFileError(f"{path}: no such video (task.video: an MP4 file, a folder of PNG frames, or a dataset shard .h5)")
    if path.is_dir():
        return _png_folder(path), None
    if path.suffix == ".h5":
        return _shard_rollout(path, rollout)
    if path.suffix.lower() in VIDEO_SUFFIXES:
        return _video_file(path), None
    raise VideoFileError(f"{path}: a {path.suffix or 'suffixless'} file, expected one of {', '.join(VIDEO_SUFFIXES)}, .h5 or a folder of PNGs")


def read_actions(path: str | Path) -> np.ndarray:
    """Actions [T, A] float32 from a ``.npy`` file or a comma-separated text file (one frame a row)."""
    path = Path(path)
    if not path.is_file():
        raise VideoFileError(f"{path}: no such actions file (task.actions: .npy, or .csv with one frame a row)")
    actions = np.load(path) if path.suffix == ".npy" else np.loadtxt(path, delimiter=",", ndmin=2)
    if actions.ndim != 2:
        raise VideoFileError(f"{path}: actions of shape {list(actions.shape)}, expected [T, A] (one frame a row)")
    return actions.astype(np.float32)


def natural_key(path: Path) -> list:
    """Sort key of a file name with its numbers read as numbers: frame_2.png before frame_10.png."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name)]


def _png_folder(folder: Path) -> np.ndarray:
    files = sorted(folder.glob("*.png"), key=natural_key)
    if not files:
        raise VideoFileError(f"{folder}: no *.png frames in the folder")
    frames = [cv2.imread(str(f), cv2.IMREAD_UNCHANGED) for f in files]
    bad = next((f for f, im in zip(files, frames) if im is None), None)
    if bad is not None:
        raise VideoFileError(f"{bad}: not a readable PNG")
    for f, im in zip(files, frames):
        if im.dtype != np.uint8 or im.ndim != 3 or im.shape[2] not in (3, 4):
            kind = "grayscale" if im.ndim == 2 else f"{im.shape[2] if im.ndim == 3 else '?'}-channel"
            raise VideoFileError(f"{f}: a {kind} {im.dtype} PNG, expected RGB (or RGBA) with 8 bits per channel, as the renderer's frames")
    frames = [im[..., :3] for im in frames]  # alpha dropped
    shapes = {im.shape for im in frames}
    if len(shapes) > 1:
        raise VideoFileError(f"{folder}: frames of different sizes {sorted(shapes)}")
    return np.stack([cv2.cvtColor(im, cv2.COLOR_BGR2RGB) for im in frames])


def _video_file(path: Path) -> np.ndarray:
    capture = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        frames.append(cv2.cvtColor(frame, cv2.COLOR_BGR2RGB))
    capture.release()
    if not frames:
        raise VideoFileError(f"{path}: no frame could be decoded (not a video, or a codec OpenCV lacks)")
    return np.stack(frames)


def _shard_rollout(path: Path, rollout: int) -> tuple[np.ndarray, np.ndarray | None]:
    try:
        f = h5py.File(path, "r")
    except OSError as error:
        raise VideoFileError(f"{path}: not a readable HDF5 file ({error}); task.video takes a dataset shard .h5, a video file or a "
                             "folder of PNGs") from None
    with f:
        n = f["rollout_ids"].shape[0] if "rollout_ids" in f else 0
    if not 0 <= rollout < n:
        raise VideoFileError(f"{path}: task.rollout={rollout}, the shard holds rollouts 0..{n - 1} (positions in the file)")
    shard = read_shard(path, images=True, rollouts=rollout + 1)
    if shard.images is None:
        raise VideoFileError(f"{path}: no 'images' (generated with data.render=false): nothing to ground from")
    actions = shard.actions[rollout]
    return shard.images[rollout], (actions if actions.shape[-1] > 0 else None)
