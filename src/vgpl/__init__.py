"""vgpl: Visual Grounding of Learned Physical Models (Li et al., ICML 2020) as a research framework."""

__version__ = "0.1.0"

from omegaconf import OmegaConf

from vgpl.hardware import fast_precision

# ${fast_precision:bf16-mixed}: bf16 where the hardware has it, fp32 where a CPU would emulate it
OmegaConf.register_new_resolver("fast_precision", fast_precision, replace=True)


def __getattr__(name: str):
    """``vgpl.Grounder``, imported on first use (``import vgpl`` stays light)."""
    if name == "Grounder":
        from vgpl.grounder import Grounder

        return Grounder
    raise AttributeError(f"module 'vgpl' has no attribute {name!r}")
