"""Is VGPL's future error really lower than an ablation's? The paper's Table 2 compares means over
test videos, and a few diverging videos can decide a mean. This pairs the videos (same rollout ids)
and bootstraps the mean difference, so a table can say when a gap is noise."""

from __future__ import annotations

import torch


def paired_bootstrap(reference: torch.Tensor, other: torch.Tensor, n_boot: int = 10000, level: float = 0.95, seed: int = 0) -> dict:
    """Mean of ``other - reference`` over paired videos [R], its percentile bootstrap interval at
    ``level``, and the share of videos where ``reference`` is lower (ties count half)."""
    diff = (other - reference).double()
    generator = torch.Generator().manual_seed(seed)
    means = diff[torch.randint(len(diff), (n_boot, len(diff)), generator=generator)].mean(1)
    tail = (1 - level) / 2
    low, high = torch.quantile(means, torch.tensor([tail, 1 - tail], dtype=means.dtype)).tolist()
    share = float(((diff > 0).double() + 0.5 * (diff == 0).double()).mean())
    return {"mean_diff": float(diff.mean()), "low": low, "high": high, "reference_lower_share": share, "videos": len(diff)}
