"""Description of the machine a benchmark ran on (printed with every benchmark's JSON)."""

from __future__ import annotations

import os
import platform

import torch

from vgpl.hardware import ISA_FLAGS, bf16_native, cpu_info


def describe() -> dict:
    cpu, flags = cpu_info()
    return {
        "cpu": cpu,
        "isa": [flag for flag in ISA_FLAGS if flag in flags],
        "bf16_native": bf16_native(flags),
        "cores": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),  # the cores this process may run on
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "python": platform.python_version(),
    }
