"""Description of the machine a benchmark ran on (printed with every benchmark's JSON)."""

from __future__ import annotations

import os
import platform
import subprocess
from pathlib import Path

import torch

import vgpl
from vgpl.hardware import ISA_FLAGS, bf16_native, cpu_family_model, cpu_info


def code_commit() -> str | None:
    """The commit of the vgpl code this process imports ("+changes" when its tree differs), or None
    outside a git checkout: which version of the code a benchmark line timed."""
    where = Path(vgpl.__file__).resolve().parent
    try:
        commit = subprocess.run(["git", "-C", str(where), "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
        changed = subprocess.run(["git", "-C", str(where), "status", "--porcelain", "--", "."], capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None
    return commit + ("+changes" if changed else "")


def describe() -> dict:
    cpu, flags = cpu_info()
    return {
        "cpu": cpu,
        "cpu_generation": cpu_family_model(),
        "isa": [flag for flag in ISA_FLAGS if flag in flags],
        "bf16_native": bf16_native(flags),
        "cores": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),  # the cores this process may run on
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "python": platform.python_version(),
        "code": code_commit(),
    }
