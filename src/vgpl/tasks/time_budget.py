"""A wall-clock budget for a whole pipeline, shared among its trainings (``task.time_budget``).

Each training stops at its ``trainer.max_time``, but the work between the trainings (generating
the videos, the identifiability sweep, exporting proposals, the evaluations) has no clock: on a
slow machine it alone can push a run that fits its trainings' minutes past the total a preset
promises (the quick preset's 10 minutes). The budget
gives each training, before it starts, at most its planned max_time scaled by

    (total - elapsed - reserve_s) / (the planned max_time of this and every later training),

so that a run that is late catches up in its trainings, in proportion to their planned lengths,
and one on time is left as it was. ``reserve_s`` is held back for the untimed work still ahead.
No training gets less than ``floor`` of its plan: past that the budget is overrun (and says so),
rather than training a module for no steps.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

from lightning.pytorch.callbacks import Timer

log = logging.getLogger(__name__)


def seconds(max_time, key: str = "trainer.max_time") -> float | None:
    """A Trainer's ``max_time`` ("DD:HH:MM:SS", a dict of timedelta's keywords, or None) in
    seconds, parsed as Lightning's Timer parses it; anything else is refused by its config ``key``."""
    if max_time is None:
        return None
    try:
        return Timer(duration=max_time).time_remaining()
    except Exception as e:  # Lightning's MisconfigurationException, or timedelta's TypeError / AttributeError
        raise ValueError(f"{key}={max_time!r}: expected a duration as trainer.max_time takes it, \"DD:HH:MM:SS\" "
                         f"(e.g. \"00:00:09:30\") or a dict of timedelta keywords ({{seconds: 570}}), or null") from e


def scaled_max_time(planned_s: float, ahead_s: float, left_s: float, floor: float) -> float:
    """The max_time (s) for a training planned at ``planned_s`` when ``ahead_s`` seconds of
    planned trainings (this one's included) must fit in ``left_s``: unchanged when they fit, else
    its share of ``left_s``, never below ``floor x planned_s``."""
    if ahead_s <= 0 or left_s >= ahead_s:
        return planned_s
    return max(planned_s * max(left_s, 0.0) / ahead_s, planned_s * floor)


class TimeBudget:
    """Hands out max_time to a pipeline's trainings in their order.

    ``planned`` maps each training step, in the order it will run, to its planned max_time in
    seconds (None: no clock; it is left so and not counted). ``total_s`` None turns the budget off
    (``reserve_s`` and ``floor`` then do nothing).
    The budget's clock (``time.perf_counter`` unless given) starts when it is made.
    """

    def __init__(self, total_s: float | None, planned: dict[str, float | None], reserve_s: float = 0.0, floor: float = 1.0,
                 clock: Callable[[], float] | None = None):
        if total_s is not None and total_s <= 0:
            raise ValueError(f"task.time_budget.total: expected a positive duration, got {total_s} s")
        if reserve_s < 0:
            raise ValueError(f"task.time_budget.reserve_s: expected seconds >= 0 held back for the untimed steps, got {reserve_s}")
        if not 0.0 < floor <= 1.0:
            raise ValueError(f"task.time_budget.floor: expected a fraction in (0, 1], got {floor}")
        self.total_s, self.reserve_s, self.floor = total_s, float(reserve_s), float(floor)
        self.ahead = dict(planned)
        self.clock = clock or time.perf_counter
        self.start = self.clock()
        self.given: dict[str, dict] = {}  # step -> {"planned_s", "max_time_s", "left_s"} for the report

    def max_time(self, step: str) -> float | None:
        """The max_time (s) for ``step``, which starts now; call it once per training. It is the
        planned one unless ``shortened(step)``."""
        return self.max_time_together([step])

    def max_time_together(self, steps: list[str]) -> float | None:
        """The max_time (s) for ``steps``, which all start now and run at once: the time their plans
        take one after another, scaled as one training's plan is scaled (None when one of them has
        no clock). Every step gets that whole time, as they share the machine throughout."""
        planned = [self.ahead.pop(step) for step in steps]
        if any(p is None for p in planned):
            return None
        group = sum(planned)
        if self.total_s is None:
            return group
        ahead = group + sum(p for p in self.ahead.values() if p is not None)
        left = self.total_s - (self.clock() - self.start) - self.reserve_s
        given = scaled_max_time(group, ahead, left, self.floor)
        for step in steps:
            self.given[step] = {"planned_s": group, "max_time_s": round(given, 1), "left_s": round(left, 1)}
        if given < group:
            who, whose = (f"{steps[0]} gets", "its") if len(steps) == 1 else (f"{' and '.join(steps)}, side by side, get", "their")
            overrun = " (at its floor: the budget will be overrun)" if given <= group * self.floor else ""
            log.warning("task.time_budget: %s max_time %.0f s of %s planned %.0f s; %.0f s of the budget remain "
                        "for %.0f s of planned training%s", who, given, whose, group, max(left, 0.0), ahead, overrun)
        return given

    def shortened(self, step: str) -> bool:
        """Whether the budget gave ``step`` (already handed its max_time) less than its plan."""
        g = self.given.get(step)
        return g is not None and g["max_time_s"] < g["planned_s"]
