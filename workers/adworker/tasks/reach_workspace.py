"""reach-workspace: an arm on a fixed base reaches targets spread over a workspace.

The manipulator's first task: the base link stands fixed where its URDF puts it (as
diagonal-gesture's), and each episode draws ``targets`` points uniformly from a ball
(``centre``, ``radius``) with the episode's seeded random numbers, so a design is judged
on the workspace, not on one point. The episode is split into equal shares, one per
target in turn; the policy observes the current target and the vector from the distal
tip to it. The distal tip is the far end of ``distal_link`` (its shape centre plus half
its length along its long axis; by default diagonal-gesture's choice of link).

Success at a target: exp(-d / ``tolerance``), d the tip's distance from it (m): 1 on
it, 0.37 a tolerance away, 0.05 at three, never quite 0, so a search over poses (the
``fast`` learner's) is led towards the workspace from anywhere. Metric per step: the
success at the current target; reward: the metric. Score: the mean over the targets of
the success at the last step of each target's share (the pose it is left holding, not
a pass on the way). Each evaluation episode reports
``task.distance``: the mean of those final distances (m). A distal link no joint moves
(the fixed base itself) is refused when the env is built.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import ClassVar

import numpy as np

from adclient.builtin_tasks import ReachWorkspaceOptions
from adworker.tasks.base import Task
from adworker.tasks.diagonal_gesture import TARGET_COLOUR, DiagonalGesture
from adworker.tasks.engine import EngineRobot, EngineSimulator
from adworker.tasks.markers import Marker
from adworker.tasks.snapshot import Snapshot

OTHER_TARGET_COLOUR = (0.55, 0.8, 0.55)


class ReachWorkspace(Task[ReachWorkspaceOptions]):
    name: ClassVar[str] = "reach-workspace"
    fixed_base: ClassVar[bool] = True
    reads_contacts: ClassVar[bool] = False
    default_episode_steps: ClassVar[int] = 48
    score_rule: ClassVar[str] = (
        "the mean over the targets of the per-step metric at the last step of each "
        "target's share of the episode"
    )

    def __init__(
        self, robot: EngineRobot, sim: EngineSimulator, options: ReachWorkspaceOptions
    ) -> None:
        super().__init__(robot, sim, options)
        self.distal = DiagonalGesture.distal_index(robot, options.distal_link)
        if self.distal == 0:
            raise ValueError(
                f"reach-workspace: distal_link {robot.link_names[0]!r} is the fixed base: "
                "no joint moves it"
            )
        self.steps = options.episode_steps or self.default_episode_steps
        if options.targets > self.steps:
            raise ValueError(
                f"reach-workspace: targets ({options.targets}) must be at most the "
                f"episode's {self.steps} steps"
            )
        self.ends = [(i + 1) * self.steps // options.targets - 1 for i in range(options.targets)]
        """The step (0-based) at which each target's share ends."""
        self.targets = np.zeros((options.targets, 3))
        self._step = 0
        self._distances: list[float] = []

    def reset(self, snapshot: Snapshot) -> None:
        options = self.options
        direction = self.rng.normal(size=(options.targets, 3))
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        reach = options.radius * np.cbrt(self.rng.uniform(size=(options.targets, 1)))
        self.targets = np.asarray(options.centre) + direction * reach
        self._step = 0
        self._distances = []

    def tip(self, snapshot: Snapshot) -> np.ndarray:
        """The far end of the distal link (world, m)."""
        half = self.robot.geometry[self.distal].length / 2
        return snapshot.centre(self.distal) + np.asarray(snapshot.axis(self.distal)) * half

    def target(self) -> np.ndarray:
        """The target of the coming step."""
        step = min(self._step, self.steps - 1)
        return self.targets[step * len(self.targets) // self.steps]

    def observation_size(self) -> int:
        return 6

    def observation(self, snapshot: Snapshot) -> list[float]:
        target = self.target()
        return [*target.tolist(), *(target - self.tip(snapshot)).tolist()]

    def metric(self, snapshot: Snapshot) -> float:
        distance = float(np.linalg.norm(self.tip(snapshot) - self.target()))
        if self._step in self.ends:
            self._distances.append(distance)
        self._step += 1
        return math.exp(-distance / self.options.tolerance)

    def score(self, metric: list[float]) -> float:
        return sum(metric[end] for end in self.ends if end < len(metric)) / len(self.ends)

    def metrics(self, snapshot: Snapshot) -> Mapping[str, float]:
        return {"distance": float(np.mean(self._distances))} if self._distances else {}

    def markers(self, snapshot: Snapshot) -> Sequence[Marker]:
        current = min(self._step, self.steps - 1) * len(self.targets) // self.steps
        return [
            Marker(
                (float(point[0]), float(point[1]), float(point[2])),
                TARGET_COLOUR if i == current else OTHER_TARGET_COLOUR,
                f"target {i + 1}",
            )
            for i, point in enumerate(self.targets)
        ]
