"""Keep freed memory in the process for reuse, instead of returning it to the OS after every step.

glibc's malloc serves large blocks (above a threshold it raises as blocks are freed, at most 32 MB)
with fresh mmap calls and returns the top of its heap to the OS once more than a trim threshold lies
free there. A training step on a graph frees and allocates tens of per-edge tensors of a few MB each,
and every fresh page costs a page fault on first touch. Raising the thresholds keeps those pages
mapped: the same arithmetic, fewer faults. The gain depends on the step (docs/benchmarks.md); the
cost is that up to ``trim_threshold`` of freed memory stays in the process.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools

M_TRIM_THRESHOLD, M_TOP_PAD, M_MMAP_THRESHOLD = -1, -2, -3  # mallopt parameters (glibc's malloc.h)


@functools.cache
def _libc() -> ctypes.CDLL | None:
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
    except OSError:
        return None
    return libc if libc is not None and hasattr(libc, "mallopt") else None


def keep_freed_memory(mmap_threshold: int = 32 << 20, trim_threshold: int = 1 << 30, top_pad: int = 256 << 20) -> bool:
    """Set glibc malloc's mmap threshold, trim threshold and top pad (bytes) for this process and the
    processes it forks. Returns whether they were set: False where the C library has no ``mallopt``
    (not glibc: macOS, musl), where nothing changes."""
    libc = _libc()
    if libc is None:
        return False
    return all(libc.mallopt(param, int(value)) == 1 for param, value in
               ((M_MMAP_THRESHOLD, mmap_threshold), (M_TRIM_THRESHOLD, trim_threshold), (M_TOP_PAD, top_pad)))
