"""Is VGPL's future error really lower than an ablation's? The paper's Table 2 compares means over
test videos, and a few diverging videos can decide a mean. This pairs the videos (same rollout ids)
and bootstraps the mean difference, so a table can say when a gap is noise. Beside it, an exact
sign test asks the question a heavy tail cannot swing: on how many videos is VGPL the lower, and
could a coin have done as well? (A heavy-tailed error can tie in the mean and not in most videos.)"""

from __future__ import annotations

import math

import torch


def sign_test_p(diff: torch.Tensor) -> float:
    """Two-sided exact sign test of paired differences [R]: the probability, if each nonzero
    difference were a fair coin's sign, of a split at least as uneven as this one (ties and NaNs,
    e.g. two rollouts diverged to inf, dropped)."""
    positive, negative = int((diff > 0).sum()), int((diff < 0).sum())
    n, fewer = positive + negative, min(positive, negative)
    if n == 0:
        return 1.0
    return min(1.0, 2 * sum(math.comb(n, i) for i in range(fewer + 1)) / 2**n)


def per_video_map(rollout_ids, values) -> dict[str, float]:
    """{rollout id (str): value}, one entry a video, as a record keeps it for ``paired_values``.
    rollout_ids [R], values [R]; refused when their lengths differ."""
    return {str(int(i)): float(v) for i, v in zip(rollout_ids, values, strict=True)}


def paired_values(reference: dict, other: dict) -> tuple[list[str], torch.Tensor, torch.Tensor]:
    """The rollout ids both per-video maps ({rollout id (str): value}) hold, in id order, and each
    map's values at them [R] (empty when the two share no video)."""
    ids = sorted(set(reference) & set(other), key=int)
    return ids, torch.tensor([reference[i] for i in ids]), torch.tensor([other[i] for i in ids])


def paired_bootstrap(reference: torch.Tensor, other: torch.Tensor, n_boot: int = 10000, level: float = 0.95, seed: int = 0) -> dict:
    """Mean of ``other - reference`` over paired videos [R], its percentile bootstrap interval at
    ``level``, the share of videos where ``reference`` is lower (ties count half) and that share's
    two-sided sign-test p (``sign_test_p``)."""
    diff = (other - reference).double()
    generator = torch.Generator().manual_seed(seed)
    means = diff[torch.randint(len(diff), (n_boot, len(diff)), generator=generator)].mean(1)
    tail = (1 - level) / 2
    low, high = torch.quantile(means, torch.tensor([tail, 1 - tail], dtype=means.dtype)).tolist()
    share = float(((diff > 0).double() + 0.5 * (diff == 0).double()).mean())
    return {"mean_diff": float(diff.mean()), "low": low, "high": high, "reference_lower_share": share,
            "sign_p": sign_test_p(diff), "videos": len(diff)}
