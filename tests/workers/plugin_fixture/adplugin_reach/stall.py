"""The stall learner: one call that never returns to the worker's checks (or an
allocation of 1 GiB), as a learner's C loop or a huge buffer would."""

from __future__ import annotations

import re
import time
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np

from adplugin_reach import StallOptions
from adworker.learners import Learner, TrainResult


class Stall(Learner):
    name: ClassVar[str] = "stall"
    default_steps: ClassVar[int] = 0

    def __init__(self, options: StallOptions | None) -> None:
        super().__init__(options)
        self.way = (options or StallOptions()).way

    def train(
        self, env: Any, *, steps: int, seed: int, check: Callable[[], None], **_: Any
    ) -> TrainResult:
        check()
        if self.way == "sleep":
            time.sleep(3600)
        elif self.way == "backtrack":
            re.match(r"(a+)+$", "a" * 64 + "b")
        elif self.way == "allocate":  # 1 GiB, every page written (past a test's limit)
            hoard = [np.ones(1 << 23) for _ in range(16)]
            del hoard
        action = np.zeros(env.joint_count, dtype=np.float32)
        return TrainResult(policy=lambda _observation: action, train_steps=0)
