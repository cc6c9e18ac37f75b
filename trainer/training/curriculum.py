"""The lift curriculum: the training lift target starts low and rises with success."""

from __future__ import annotations

import math
from collections import deque
from typing import Any

from trainer.config import RewardConfig
from trainer.errors import TrainerError
from trainer.training.outcomes import ObjectOutcomes


class LiftCurriculum:
    """The training lift target (m): starts at ``reward.h_bar_start`` and rises by
    ``h_bar_increment`` whenever the running success at it reaches ``h_bar_promote`` over a
    full window of ended episodes, until it is ``reward.h_bar``. One target for every object
    over the last ``window`` episodes, or (``reward.curriculum_per_object``) one per object id
    over that object's last ``window / num_objects`` episodes (at least 16)."""

    MIN_OBJECT_WINDOW = 16

    def __init__(self, reward: RewardConfig, num_objects: int, window: int) -> None:
        self.reward = reward
        self.per_object = reward.curriculum_per_object
        self.h_bars = [reward.h_bar_start] * num_objects
        if self.per_object:
            window = max(self.MIN_OBJECT_WINDOW, math.ceil(window / num_objects))
        self.window = window
        self.outcomes: deque[bool] = deque(maxlen=window)
        self.by_object = ObjectOutcomes(window)

    @property
    def active(self) -> bool:
        """Some object's target is still below the task's ``h_bar``."""
        return min(self.h_bars) < self.reward.h_bar

    def targets(self) -> float | list[float]:
        """What ``GraspTask.set_lift_target`` takes."""
        return list(self.h_bars) if self.per_object else self.h_bars[0]

    def mean_h_bar(self) -> float:
        return sum(self.h_bars) / len(self.h_bars)

    def record(self, object_ids: list[int], successes: list[bool]) -> None:
        """Ended episodes: their target object and success at the target they trained for."""
        self.outcomes.extend(successes)
        self.by_object.extend(object_ids, successes)

    def rate(self) -> float:
        """Running success at the current target(s): over all episodes, or the mean of the
        objects' own rates (0 before any episode ended)."""
        if self.per_object:
            rate = self.by_object.rate()
            return 0.0 if math.isnan(rate) else rate
        return sum(self.outcomes) / len(self.outcomes) if self.outcomes else 0.0

    def promote(self) -> bool:
        """Raise every target whose window is full and successful enough; True if any rose
        (its window then starts again)."""
        if not self.per_object:
            h_bar = next_lift_target(
                self.h_bars[0], self.rate(), len(self.outcomes) == self.window, self.reward
            )
            if h_bar == self.h_bars[0]:
                return False
            self.h_bars = [h_bar] * len(self.h_bars)
            self.outcomes.clear()
            return True
        changed = False
        for object_id, window in self.by_object.by_object.items():
            h_bar = next_lift_target(
                self.h_bars[object_id], sum(window) / max(len(window), 1),
                len(window) == self.window, self.reward,
            )
            if h_bar != self.h_bars[object_id]:
                self.h_bars[object_id] = h_bar
                window.clear()
                changed = True
        return changed

    def state_dict(self) -> dict[str, Any]:
        """The checkpoint's ``h_bar`` (a number, or one per object) and ``target_outcomes``."""
        if self.per_object:
            return {"h_bar": list(self.h_bars), "target_outcomes": self.by_object.state_dict()}
        return {"h_bar": self.h_bars[0], "target_outcomes": list(self.outcomes)}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """From a checkpoint's ``h_bar`` and ``target_outcomes`` (those from before the
        curriculum existed lack both: the task's ``h_bar``, nothing recorded)."""
        h_bar = state.get("h_bar", self.reward.h_bar)
        outcomes = state.get("target_outcomes", [])
        if isinstance(h_bar, (int, float)) == self.per_object:
            raise TrainerError(
                "checkpoint: its lift curriculum is "
                f"{'one target for all objects' if self.per_object else 'per object'}, the "
                "config's is not; resume with the run's own reward.curriculum_per_object"
            )
        if self.per_object:
            self.h_bars = [float(h) for h in h_bar]
            self.by_object.load_state_dict(outcomes)
        else:
            self.h_bars = [float(h_bar)] * len(self.h_bars)
            self.outcomes.extend(outcomes)


def next_lift_target(
    h_bar: float, target_rate: float, window_full: bool, reward: RewardConfig
) -> float:
    """The curriculum's rule: raise a training lift target ``h_bar`` (m) once the running
    success at it (``target_rate``) reaches ``reward.h_bar_promote`` over a full window of
    episodes."""
    if h_bar >= reward.h_bar or not window_full or target_rate < reward.h_bar_promote:
        return h_bar
    return round(min(h_bar + reward.h_bar_increment, reward.h_bar), 6)  # no 0.09000000000000001
