"""What the CPU can do fast: its vector extensions, and whether bf16 arithmetic is native.

On a CPU without ``avx512_bf16`` or ``amx_bf16`` PyTorch emulates bf16 and
``trainer.precision=bf16-mixed`` is slower than fp32. The flags promise native bf16, not speed:
docs/benchmarks.md gives the measured steps on CPUs with and without them.
"""

from __future__ import annotations

import functools
import platform

# the extensions that decide the speed of this project's CPU training
ISA_FLAGS = ("avx2", "avx512f", "avx512_bf16", "avx512_vnni", "amx_bf16", "amx_tile")
BF16_FLAGS = frozenset({"avx512_bf16", "amx_bf16"})


def cpuinfo_fields(path: str = "/proc/cpuinfo") -> dict[str, str] | None:
    """The first value of each ``key : value`` line of ``path`` (the first CPU's, where the file lists
    several), or None where it is unreadable."""
    try:
        with open(path) as f:
            lines = f.read().splitlines()
    except OSError:
        return None
    fields: dict[str, str] = {}
    for key, sep, value in (line.partition(":") for line in lines):
        if sep:
            fields.setdefault(key.strip(), value.strip())
    return fields


@functools.cache
def cpu_info(path: str = "/proc/cpuinfo") -> tuple[str, frozenset[str]]:
    """(model name, set of feature flags) of the first CPU; flags are empty where ``path`` is unreadable."""
    fields = cpuinfo_fields(path) or {}
    return fields.get("model name") or platform.processor() or "", frozenset(fields.get("flags", "").split())


def cpu_family_model(path: str = "/proc/cpuinfo") -> str | None:
    """"family F model M" of the first CPU, or None where ``path`` is unreadable or lacks them. A VM
    may name every generation of a vendor's CPUs alike ("AMD EPYC"); the family and model tell them apart."""
    fields = cpuinfo_fields(path) or {}
    family, model = fields.get("cpu family"), fields.get("model")
    return None if family is None or model is None else f"family {family} model {model}"


def bf16_native(flags: frozenset[str] | None = None) -> bool | None:
    """Whether the CPU computes bf16 natively; None where its flags cannot be read."""
    flags = cpu_info()[1] if flags is None else flags
    return bool(flags & BF16_FLAGS) if flags else None


def bf16_emulated(precision: str, on_cpu: bool, flags: frozenset[str] | None = None) -> bool:
    """Whether ``precision`` asks for bf16 on a CPU known to lack bf16 units (unknown CPU: False)."""
    return str(precision).startswith("bf16") and on_cpu and bf16_native(flags) is False


def precision_warning(precision: str, accelerator: str, cuda: bool, flags: frozenset[str] | None = None) -> str | None:
    """A warning when ``precision`` asks for bf16 on a CPU that would emulate it, else None.
    ``flags``: the CPU's feature flags (default: this machine's)."""
    if bf16_emulated(precision, accelerator == "cpu" or (accelerator == "auto" and not cuda), flags):
        return (f"trainer.precision={precision} on a CPU without avx512_bf16 or amx_bf16 ({cpu_info()[0]}): "
                "bf16 is emulated here and about 2x slower than trainer.precision=32-true")
    return None


def fast_precision(preferred: str = "bf16-mixed", cuda: bool | None = None, flags: frozenset[str] | None = None) -> str:
    """``preferred`` where it runs fast (a GPU, or a CPU with bf16 units or unreadable flags), else
    ``32-true``. The config resolver ``${fast_precision:bf16-mixed}`` (registered on ``import vgpl``)."""
    import torch

    cuda = torch.cuda.is_available() if cuda is None else cuda
    if bf16_emulated(preferred, not cuda, flags):
        return "32-true"
    return preferred
