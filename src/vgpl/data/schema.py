"""The HDF5 schema of a dataset shard (docs/data.md) and its validation.

One file per shard of a split. Every problem with a file is reported as one
:class:`DatasetError` that names the file and the key and says what was expected.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import h5py
import numpy as np

FORMAT_VERSION = 1

# attribute name -> description (all required). No time of writing: a shard file's bytes depend on its
# configuration alone, so a resumed generation writes the same files as an uninterrupted one.
ATTRS = {
    "format_version": "int schema version",
    "env": "environment name",
    "dt": "seconds per frame",
    "n_particles": "N",
    "n_instances": "M",
    "param_names": "names of the P physical parameters",
    "param_low": "[P] lower bounds of the sampled range",
    "param_high": "[P] upper bounds of the sampled range",
    "camera": "camera as JSON (intrinsics, extrinsics, convention)",
    "generator_version": "vgpl version that wrote the file",
    "seed": "base seed of the dataset",
    "split": "train or test",
    "shard": "shard index within the split",
    "config_hash": "hash of everything that determines the content",
}

# dataset name -> (dtype kind, shape template); R rollouts, T frames, N particles, M instances,
# P parameters, A action size, H x W image size
DATASETS = {
    "positions": ("f", ("R", "T", "N", 3)),
    "velocities": ("f", ("R", "T", "N", 3)),
    "instance": ("i", ("N",)),
    "rigid": ("b", ("M",)),
    "params": ("f", ("R", "P")),
    "actions": ("f", ("R", "T", "A")),
    "rollout_ids": ("i", ("R",)),
}
IMAGES = ("u", ("R", "T", "H", "W", 3))  # optional: present when rendered


class DatasetError(ValueError):
    """A dataset file is missing, unreadable, or does not follow the schema."""


@contextmanager
def reading(path: str | Path) -> Iterator[None]:
    """Reads of ``path``'s data inside turn the OS's error on a damaged chunk (h5py's ``OSError``:
    "filter returned failure", a checksum) into one DatasetError naming the file."""
    try:
        yield
    except OSError as error:
        raise DatasetError(f"{path}: its data cannot be read ({error}): a damaged file or copy; task=generate rewrites it "
                           "(it verifies every shard it resumes), or delete it") from None


def _check_shape(path: Path, key: str, shape: tuple, template: tuple, dims: dict) -> None:
    if len(shape) != len(template):
        raise DatasetError(f"{path}: '{key}' has shape {shape}, expected {template}")
    for size, sym in zip(shape, template):
        if isinstance(sym, int):
            if size != sym:
                raise DatasetError(f"{path}: '{key}' has shape {shape}, expected {template}")
        elif dims.setdefault(sym, size) != size:
            raise DatasetError(f"{path}: '{key}' has shape {shape}, expected {template} with {sym}={dims[sym]} as in the other keys")


def check_values(path: str | Path, arrays: dict, param_low, param_high) -> None:
    """The values a shape check cannot see: finite positions, velocities and actions in every
    rollout, parameters within [param_low, param_high]. ``arrays`` maps schema keys to arrays
    (``rollout_ids`` names the rollouts). Raises DatasetError naming the file, key and rollouts."""
    ids = np.asarray(arrays["rollout_ids"])
    for key in ("positions", "velocities", "actions", "params"):
        data = np.asarray(arrays[key])
        bad = ~np.isfinite(data.reshape(len(data), -1)).all(1)
        if bad.any():
            raise DatasetError(f"{path}: '{key}' holds NaN or inf in rollout(s) {ids[bad].tolist()}, expected finite values "
                               "(a diverged simulation; regenerate those rollouts or drop the file)")
    params, low, high = np.asarray(arrays["params"]), np.asarray(param_low, float), np.asarray(param_high, float)
    slack = 1e-6 * (high - low)
    out = ((params < low - slack) | (params > high + slack)).any(1)
    if out.any():
        raise DatasetError(f"{path}: 'params' of rollout(s) {ids[out].tolist()} lie outside the range [{low.tolist()}, {high.tolist()}] "
                           "of the attributes param_low/param_high")


def validate(path: str | Path) -> dict:
    """Check one shard file against the schema.

    Returns: the dimensions {R, T, N, M, P, A, (H, W)} and attributes of the file.
    Raises: DatasetError naming the file and the offending key.
    """
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: no such dataset file")
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        raise DatasetError(f"{path}: not a readable HDF5 file (truncated or foreign?): {e}") from None
    with f:
        missing = [a for a in ATTRS if a not in f.attrs]
        if "format_version" in missing:
            raise DatasetError(f"{path}: attribute 'format_version' missing: not a vgpl dataset")
        if int(f.attrs["format_version"]) != FORMAT_VERSION:
            raise DatasetError(f"{path}: format_version {int(f.attrs['format_version'])}, this vgpl reads {FORMAT_VERSION}")
        if missing:
            raise DatasetError(f"{path}: attribute(s) {missing} missing ({', '.join(ATTRS[a] for a in missing)})")
        dims: dict = {"P": len(f.attrs["param_names"])}
        for key, (kind, template) in DATASETS.items():
            if key not in f:
                raise DatasetError(f"{path}: dataset '{key}' missing (expected {kind}-typed {template})")
            ds = f[key]
            if ds.dtype.kind != kind:
                raise DatasetError(f"{path}: dataset '{key}' has dtype {ds.dtype}, expected kind '{kind}'")
            if kind == "f" and ds.dtype != np.float32:
                raise DatasetError(f"{path}: dataset '{key}' has dtype {ds.dtype}, expected float32 (as vgpl writes it)")
            _check_shape(path, key, ds.shape, template, dims)
        if "images" in f:
            _check_shape(path, "images", f["images"].shape, IMAGES[1], dims)
            if f["images"].dtype != np.uint8:
                raise DatasetError(f"{path}: dataset 'images' has dtype {f['images'].dtype}, expected uint8")
        if dims["N"] != int(f.attrs["n_particles"]) or dims["M"] != int(f.attrs["n_instances"]):
            raise DatasetError(f"{path}: attributes n_particles/n_instances disagree with 'instance'/'rigid' shapes")
        attrs = {k: f.attrs[k] for k in f.attrs}
    return {"dims": dims, "attrs": attrs}
