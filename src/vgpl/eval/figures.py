"""Figures of the evaluation (matplotlib, Agg): rigidness against observation length, predicted
against true particles, inferred against true parameters."""

from __future__ import annotations

import textwrap
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402


def rigidness_figure(curves: dict[str, list[float]], trained_at: int, title: str = ""):
    """Mean probability of the correct rigidness label against observed frames T, one line per type."""
    fig, ax = plt.subplots(figsize=(4.5, 3.2), dpi=120)
    for name, values in curves.items():
        ax.plot(np.arange(1, len(values) + 1), values, marker="o", ms=3, label=name)
    ax.axvline(trained_at, color="grey", lw=0.8, ls="--", label=f"trained at T={trained_at}")
    ax.axhline(0.5, color="grey", lw=0.5)
    ax.set(xlabel="observed frames T", ylabel="P(correct rigidness)", ylim=(0, 1.02), title=title)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def particles_figure(camera, instance: np.ndarray, truth: torch.Tensor, pred: torch.Tensor, steps: list[int], title: str = ""):
    """Projected true (filled) and predicted (rings) particles at the given future steps (1-based).
    truth, pred [n_steps, N, 3]."""
    fig, axes = plt.subplots(1, len(steps), figsize=(3.6 * len(steps), 3.0), dpi=120, squeeze=False)
    colours = plt.get_cmap("tab10")(np.asarray(instance) % 10)
    for ax, k in zip(axes[0], steps):
        t = camera.project(truth[k - 1]).numpy()
        p = camera.project(pred[k - 1]).numpy()
        ax.scatter(t[:, 0], t[:, 1], s=6, c=colours, label="truth")
        ax.scatter(p[:, 0], p[:, 1], s=14, facecolors="none", edgecolors=colours, linewidths=0.6, label="prediction")
        ax.set(xlim=(0, camera.width), ylim=(camera.height, 0), title=f"T+{k}", aspect="equal", xticks=[], yticks=[])
    axes[0, 0].legend(fontsize=7, loc="lower left")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return fig


def params_figure(truth: torch.Tensor, pred: torch.Tensor, low: float, high: float, name: str, title: str = ""):
    """Inferred against true parameter, one point per test video."""
    fig, ax = plt.subplots(figsize=(3.4, 3.2), dpi=120)
    ax.plot([low, high], [low, high], color="grey", lw=0.8)
    ax.scatter(truth.numpy(), pred.numpy(), s=8)
    ax.set(xlabel=f"true {name}", ylabel=f"inferred {name}", xlim=(low, high), ylim=(low, high), aspect="equal")
    ax.set_title(textwrap.fill(title, 34), fontsize=9)  # the figure is narrow: wrap rather than clip
    fig.tight_layout()
    return fig


def gradient_agreement_figure(starts: list[int], agreement: torch.Tensor, probes: torch.Tensor, name: str, title: str = ""):
    """Share of scenes whose rollout-loss gradient in ``name`` points to the truth against the frame
    the window starts at, one line per probe value. ``agreement`` [S, V], ``probes`` [V] normalised."""
    fig, ax = plt.subplots(figsize=(4.5, 3.2), dpi=120)
    for k, v in enumerate(probes.tolist()):
        ax.plot(starts, agreement[:, k].numpy() * 100, marker="o", ms=3, label=f"{name} at {v:+.2f}")
    ax.axhline(50, color="grey", lw=0.8, ls="--", label="a coin")
    ax.set(xlabel="window start frame", ylabel="gradient points to the truth (%)", ylim=(0, 102), title=title)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def save(fig, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path
