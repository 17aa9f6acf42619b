"""Files written whole or not at all: a writer writes a temporary file beside the target, named so
that no other writer uses it, and renames it over the target only once it is complete. A reader
sees the old file or the new one, never a part; two writers of one target each write their own
temporary file, and the last rename wins with a whole file; a failed write leaves the target as
it was and no temporary file behind."""

from __future__ import annotations

import os
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path


def temporary_path(path: Path) -> Path:
    """A file name beside ``path`` that no other writer uses: ``<name>.<pid>-<random>.tmp``."""
    return path.with_name(f"{path.name}.{os.getpid()}-{uuid.uuid4().hex[:8]}.tmp")


@contextmanager
def atomic_path(path: str | Path, place: Callable[[Path, Path], None] = os.replace) -> Iterator[Path]:
    """Yields a temporary path to write ``path``'s new content to; when the block ends without an
    error, ``place(tmp, path)`` (an atomic rename, or a caller's checked one) puts it in place. The
    temporary file is removed whatever happens. The parent folder is made if missing."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temporary_path(path)
    try:
        yield tmp
        place(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)  # placed: gone already; failed: not left behind
