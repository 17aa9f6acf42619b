"""Units shared by the learned modules: the parameter range and the trajectory statistics live
in buffers, so they travel with every checkpoint (learning_to_simulate's normalisation)."""

from __future__ import annotations

import torch

STATS = ("disp_mean", "disp_std", "pos_mean", "pos_std")


class NormalisationBuffers:
    """Mixin for an ``nn.Module``: buffers param_low/high [P], disp/pos mean and std [3]."""

    def register_normalisation(self, param_low: list[float], param_high: list[float]) -> None:
        self.register_buffer("param_low", torch.tensor(param_low, dtype=torch.float32))
        self.register_buffer("param_high", torch.tensor(param_high, dtype=torch.float32))
        for name in STATS:
            self.register_buffer(name, torch.zeros(3) if name.endswith("mean") else torch.ones(3))

    def set_stats(self, stats) -> None:
        """Copy statistics from anything with the four attributes (``NormStats``, another module)."""
        for name in STATS:
            getattr(self, name).copy_(getattr(stats, name))

    def normalise_params(self, params: torch.Tensor) -> torch.Tensor:
        """Physical units -> [-1, 1] over the range."""
        return 2.0 * (params - self.param_low) / (self.param_high - self.param_low) - 1.0

    def to_physical(self, normalised: torch.Tensor) -> torch.Tensor:
        """[-1, 1] -> physical units."""
        return self.param_low + (normalised + 1.0) * 0.5 * (self.param_high - self.param_low)
