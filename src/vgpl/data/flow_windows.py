"""Windows of video, actions and ground-truth optical flow for the DensePhysNet baseline."""

from __future__ import annotations

from torch.utils.data import Dataset

from vgpl.data.flow import farneback_flow, particle_flow
from vgpl.data.flow_cache import CachedFlow
from vgpl.data.trajectories import Rollouts


class FlowWindows(Dataset):
    """Item: frames uint8 [T + 1, H, W, 3], actions [T, A], flow [T, H, W, 2] (pixels per frame),
    params [P]. Windows start at ``start_frame`` and every ``stride``-th frame after it
    (``stride=None``: only at ``start_frame``, the evaluation protocol). With ``reference`` and
    estimated flow, items also hold ``simulator_flow`` [T, H, W, 2], to measure the estimate by.
    ``cache`` (set with estimated flow, once ``pairs_needed`` is known): the split's flow cache
    (vgpl.data.flow_cache), read instead of estimating each window's flow again."""

    def __init__(self, rollouts: Rollouts, camera, observed: int, start_frame: int = 0, stride: int | None = None, flow: str = "simulator",
                 reference: bool = False) -> None:
        if flow not in ("simulator", "farneback"):
            raise ValueError(f"model.densephysnet.flow={flow!r}: expected simulator or farneback")
        self.flow, self.reference = flow, reference and flow != "simulator"
        if rollouts.images is None:
            raise ValueError("FlowWindows needs rollouts loaded with images=True")
        self.r, self.camera, self.observed = rollouts, camera, observed
        n_rollouts, n_frames = rollouts.positions.shape[:2]
        last = n_frames - observed - 1
        if last < start_frame:
            raise ValueError(f"rollouts of {n_frames} frames are too short for {start_frame} skipped + {observed} + 1 frames")
        starts = [start_frame] if stride is None else range(start_frame, last + 1, stride)
        self.index = [(r, s) for r in range(n_rollouts) for s in starts]
        self.cache: CachedFlow | None = None

    @property
    def pairs_needed(self) -> int:
        """Frame pairs from the first frame that the windows' flows cover."""
        return max(s for _, s in self.index) + self.observed

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, k: int) -> dict:
        r, s = self.index[k]
        frames = slice(s, s + self.observed + 1)
        simulated = particle_flow(self.camera, self.r.positions[r, frames]) if self.flow == "simulator" or self.reference else None
        item = {
            "frames": self.r.images[r, frames], "actions": self.r.actions[r, s : s + self.observed],
            "flow": simulated if self.flow == "simulator" else self.cache.window(r, s, self.observed) if self.cache is not None
            else farneback_flow(self.r.images[r, frames]),
            "params": self.r.params[r],
        }
        if self.reference:
            item["simulator_flow"] = simulated
        return item
