"""vgpl: Visual Grounding of Learned Physical Models (Li et al., ICML 2020) as a research framework."""

__version__ = "0.1.0"
