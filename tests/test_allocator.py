"""keep_freed_memory: freed tensors' pages stay in the process, so allocating them again does not
fault them in again. Each case runs in a fresh process (malloc's settings are process-wide)."""

from __future__ import annotations

import subprocess
import sys

import pytest

CYCLES = """
import resource, sys, torch
from vgpl.allocator import keep_freed_memory
if sys.argv[1] == "keep":
    assert keep_freed_memory()
def cycle():  # 20 tensors of 8 MB, written, then freed: the shape of a training step's per-edge tensors
    xs = [torch.ones(2 << 20) for _ in range(20)]
    del xs
cycle()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(4):
    cycle()
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def page_faults(mode: str) -> int:
    out = subprocess.run([sys.executable, "-c", CYCLES, mode], capture_output=True, text=True, check=True)
    return int(out.stdout.split()[-1])


PAGES_PER_CYCLE = 20 * (8 << 20) // 4096


@pytest.mark.slow  # starts several processes
def test_freed_tensors_are_reused_without_page_faults():
    default, kept = page_faults("default"), page_faults("keep")
    assert default >= PAGES_PER_CYCLE  # by default at least one cycle's 160 MB is unmapped and faulted in again
    assert kept < PAGES_PER_CYCLE / 4  # kept: not a quarter of one cycle over all four
