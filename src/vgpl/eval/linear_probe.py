"""Ridge regression on frozen features (closed form): the linear decoder of DensePhysNet."""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class Ridge:
    mean: torch.Tensor  # [F]
    std: torch.Tensor  # [F]
    weight: torch.Tensor  # [F, P]
    bias: torch.Tensor  # [P]

    @classmethod
    def fit(cls, x: torch.Tensor, y: torch.Tensor, alpha: float = 1.0) -> Ridge:
        """Least squares with an L2 penalty ``alpha`` on standardised features. x [R, F], y [R, P]."""
        x, y = x.double(), y.double()
        mean, std = x.mean(0), x.std(0).clamp_min(1e-6)
        z = (x - mean) / std
        bias = y.mean(0)
        a = z.T @ z + alpha * torch.eye(z.shape[1], dtype=z.dtype)
        weight = torch.linalg.solve(a, z.T @ (y - bias))
        return cls(mean.float(), std.float(), weight.float(), bias.float())

    def predict(self, x: torch.Tensor) -> torch.Tensor:
        return ((x - self.mean) / self.std) @ self.weight + self.bias

    def state_dict(self) -> dict:
        return {"mean": self.mean, "std": self.std, "weight": self.weight, "bias": self.bias}
