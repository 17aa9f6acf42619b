"""The claim of one generation configuration on a dataset folder ``data.root/<env>``.

Runs of one configuration (a resumed run, Hydra multirun workers that split the shards) share a
folder; a run of another configuration (another seed, scene or size) is refused before it writes,
even when the two start together. The claim is ``<folder>/dataset.json`` (the configuration's
``config_hash`` and what it is made of). It is read and written under an exclusive OS lock
(``filelock``) on ``<folder>/.dataset.lock``, and checked again under that lock at the moment each
shard is renamed into place.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import h5py
from filelock import FileLock

from vgpl.atomic_write import atomic_path
from vgpl.data.schema import DatasetError

MANIFEST = "dataset.json"
LOCK = ".dataset.lock"
T = TypeVar("T")


class DatasetClaim:
    """The configuration ``config_hash`` (described by ``description``: env, seed, sizes) writing
    ``folder``. Picklable, so that worker processes place their shards through it."""

    def __init__(self, folder: str | Path, config_hash: str, description: dict) -> None:
        self.folder = Path(folder)
        self.config_hash = config_hash
        self.description = description

    @property
    def manifest(self) -> Path:
        return self.folder / MANIFEST

    def lock(self) -> FileLock:
        return FileLock(self.folder / LOCK)

    def claim(self, check_existing: Callable[[], T]) -> T:
        """Under the lock: refuse when another configuration holds the folder, run
        ``check_existing`` (it raises on shards of another configuration, so a folder written
        before claims existed is never claimed over), then record this configuration. Returns
        what ``check_existing`` returns."""
        with self.lock():
            self._check(required=False)
            result = check_existing()
            if not self.manifest.exists():
                with atomic_path(self.manifest) as tmp:
                    tmp.write_text(json.dumps({"config_hash": self.config_hash, **self.description}, indent=1, default=str))
        return result

    def place(self, tmp: Path, path: Path) -> None:
        """Rename the finished shard ``tmp`` to ``path`` under the lock, when the folder is still
        claimed by this configuration and ``path`` is not a shard of another; otherwise ``tmp`` is
        removed, ``path`` is left as it was, and DatasetError names the file that refused it."""
        with self.lock():
            try:
                self._check(required=True)
                found = written_by(path)
                if found is not None and found != self.config_hash:
                    raise DatasetError(f"{path}: written meanwhile by another configuration (config_hash {found}, this run "
                                       f"{self.config_hash}); this run's shard was not placed")
            except DatasetError:
                tmp.unlink(missing_ok=True)
                raise
            os.replace(tmp, path)

    def _check(self, required: bool) -> None:
        if not self.manifest.exists():
            if required:
                raise DatasetError(f"{self.manifest}: missing while this run writes {self.folder} (deleted during the run?); "
                                   "this run's shard was not placed")
            return
        try:
            found = json.loads(self.manifest.read_text())
        except (OSError, ValueError) as error:
            raise DatasetError(f"{self.manifest}: unreadable ({error}); it records which configuration writes {self.folder}: "
                               "delete it only together with the folder's shards") from error
        if found.get("config_hash") != self.config_hash:
            theirs = ", ".join(f"{k} {found.get(k)}" for k in ("config_hash", "seed"))
            ours = ", ".join(f"{k} {v}" for k, v in (("config_hash", self.config_hash), ("seed", self.description.get("seed"))))
            raise DatasetError(f"{self.manifest}: {self.folder} belongs to another configuration ({theirs}; this run: {ours}), "
                               "whose run may still be writing it; choose another data.root, or delete the folder to replace it")


def written_by(path: Path) -> str | None:
    """The ``config_hash`` attribute of the shard file ``path``; None when there is no readable one."""
    if not path.exists():
        return None
    try:
        with h5py.File(path, "r") as f:
            return str(f.attrs["config_hash"])
    except (OSError, KeyError):
        return None
