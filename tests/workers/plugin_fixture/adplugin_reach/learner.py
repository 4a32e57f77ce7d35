"""The learner: a constant policy, no training. Its ``train`` is of the interface
before issue 38 (no ``start``, ``keep_checkpoint`` or ``reporting``), as a plugin
written then is: the worker still runs it, with a DeprecationWarning."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np

from adplugin_reach import HoldOptions
from adworker.learners import Learner, TrainResult


class Hold(Learner):
    name: ClassVar[str] = "hold"
    default_steps: ClassVar[int] = 0

    def __init__(self, options: HoldOptions | None) -> None:
        super().__init__(options)
        self.pose = (options or HoldOptions()).pose

    def train(
        self, env: Any, *, steps: int, seed: int, check: Callable[[], None] = lambda: None
    ) -> TrainResult:
        action = np.full(env.joint_count, self.pose, dtype=np.float32)
        return TrainResult(policy=lambda _observation: action, train_steps=0)
