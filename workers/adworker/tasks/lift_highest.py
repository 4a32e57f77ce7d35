"""lift-highest: a free robot of 3 to 5 links, any tree, raises its highest point.

The task the fused representation is exercised on: the design space lists several
candidate tree structures (chains, stars, forks) over the same parts, and which tree
can hold a point highest depends on the structure as much as on the specs. The robot
starts lying on the ground along +x (like stand-up). Score: the height of the
highest point of the body (the top of any link's shape, cylinder rims included),
averaged over the second half of each evaluation episode. Reward: that height per
step. A jump counts only while it lasts, so the score favours a stable raised pose:
a link propped upright by the others, a tripod, an arch.
"""

from __future__ import annotations

from typing import ClassVar

from adclient.plugins import SimulatorOptions
from adworker.tasks.base import Task
from adworker.tasks.snapshot import Snapshot


class LiftHighest(Task[SimulatorOptions]):
    name: ClassVar[str] = "lift-highest"
    fixed_base: ClassVar[bool] = False

    def metric(self, snapshot: Snapshot) -> float:
        return max(snapshot.top)
