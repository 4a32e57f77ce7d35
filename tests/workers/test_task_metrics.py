"""A task's own metrics and the points it marks in robot.png (issue 39), on real PyBullet
envs: what a task returns is checked by a whitelist, merged as ``task.<name>``, and its
markers are drawn where the camera sees their points."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import numpy as np
import pytest

from adclient.plugins import SimulatorOptions
from adworker import designs
from adworker.learners import evaluate_policy
from adworker.task_metrics import MAX_TASK_METRICS, checked_task_metrics, merge_task_metrics
from adworker.tasks.base import RobotEnv, Task
from adworker.tasks.engine import Camera
from adworker.tasks.markers import (
    DOT_RADIUS,
    MAX_MARKERS,
    Marker,
    checked_markers,
    draw_markers,
    label_places,
)
from adworker.tasks.snapshot import Snapshot
from tests.workers.robots import write_urdf

GROUND_AND_SKY = 40
"""A pixel of the ground or the sky is grey: its channels differ by less than this."""


def _hold(env: Any) -> Any:
    action = np.zeros(env.joint_count, dtype=np.float32)
    return lambda _observation: action


@pytest.mark.parametrize(
    ("values", "named"),
    [
        ({"tip distance": 1.0}, "task metric name 'tip distance' must match"),
        ({"a.b": 1.0}, "task metric name 'a.b' must match"),
        ({"": 1.0}, "task metric name '' must match"),
        ({"<script>": 1.0}, "task metric name '<script>' must match"),
        ({"x" * 65: 1.0}, "must match"),
        ({"é": 1.0}, "task metric name 'é' must match"),
        ({3: 1.0}, "task metric name '3' must match"),
        ({"d": float("nan")}, "task metric 'd' must be finite, got nan"),
        ({"d": -math.inf}, "task metric 'd' must be finite, got -inf"),
        ({"d": True}, "task metric 'd' must be a number, got bool"),
        ({"d": "1.0"}, "task metric 'd' must be a number, got str"),
        ({"d": None}, "task metric 'd' must be a number, got NoneType"),
        ({"d": [1.0]}, "task metric 'd' must be a number, got list"),
        ({f"m{i}": 1.0 for i in range(MAX_TASK_METRICS + 1)}, "at most 32 metrics, got 33"),
        ([("d", 1.0)], "a mapping of names to numbers, got list"),
        (None, "a mapping of names to numbers, got NoneType"),
    ],
)
def test_a_task_metric_that_is_not_allowed_is_named(values: Any, named: str) -> None:
    with pytest.raises(ValueError, match="task") as raised:
        checked_task_metrics(values)
    assert named in str(raised.value)


def test_task_metrics_are_floats_merged_as_task_names_and_averaged_over_episodes() -> None:
    episodes = [
        checked_task_metrics({"tip_distance": np.float32(0.5), "hits": 2}),
        checked_task_metrics({"tip_distance": 0.25}),
    ]
    assert episodes[0] == {"tip_distance": 0.5, "hits": 2.0}
    assert all(type(value) is float for value in episodes[0].values())
    own = {"mass": 3.0, "time_total_s": 1.0}
    merged = merge_task_metrics(own, episodes)
    assert merged == {**own, "task.tip_distance": 0.375, "task.hits": 2.0}
    assert merge_task_metrics(own, [{}, {}]) == own

    # A catalogue named "task" reports task.<entry>: a task metric of that name is refused.
    with pytest.raises(ValueError) as raised:
        merge_task_metrics({"task.cost": 2.0}, [{"cost": 1.0}])
    assert "task metric 'cost' is reported as 'task.cost', a metric the trial already has" in str(
        raised.value
    )


class HostileTask(Task[SimulatorOptions]):
    """Reports and marks what each test gives it."""

    name: ClassVar[str] = "hostile"
    fixed_base: ClassVar[bool] = True
    reads_contacts: ClassVar[bool] = False
    reported: ClassVar[Any] = {}
    marked: ClassVar[Any] = ()

    def metric(self, snapshot: Snapshot) -> float:
        return 0.0

    def metrics(self, snapshot: Snapshot) -> Mapping[str, float]:
        return self.reported

    def markers(self, snapshot: Snapshot) -> Sequence[Marker]:
        return self.marked


@pytest.fixture
def hostile_env(tmp_path):
    robot = designs.crossed_chain()
    urdf_path = write_urdf(robot, tmp_path / "robot.urdf")
    env = RobotEnv(HostileTask, design=robot, urdf_path=urdf_path, options=SimulatorOptions())
    yield env
    env.close()


def test_an_evaluation_fails_naming_a_task_metric_that_is_not_allowed(
    hostile_env, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(HostileTask, "reported", {"ok": 1.0, "dist; DROP": 2.0})
    with pytest.raises(ValueError, match="task metric name 'dist; DROP' must match"):
        evaluate_policy(hostile_env, _hold(hostile_env), [0])
    monkeypatch.setattr(HostileTask, "reported", {"ok": math.nan})
    with pytest.raises(ValueError, match="task metric 'ok' must be finite"):
        evaluate_policy(hostile_env, _hold(hostile_env), [0])
    monkeypatch.setattr(HostileTask, "reported", {"ok": 1})
    episodes = evaluate_policy(hostile_env, _hold(hostile_env), [0, 1])
    assert [episode.task_metrics for episode in episodes] == [{"ok": 1.0}, {"ok": 1.0}]


@pytest.mark.parametrize(
    ("marked", "named"),
    [
        ([(0.0, 0.0, 1.0)], "marker 0: a Marker, got tuple"),
        ([Marker((0, 0, 1)), Marker((0, math.nan, 1))], "marker 1.position: numbers must be"),
        ([Marker((0, 0, 1e6))], "marker 0.position: (0.0, 0.0, 1000000.0) is more than 1000"),
        ([Marker((0, 0))], "marker 0.position: three numbers"),  # type: ignore[arg-type]
        ([Marker((0, 0, True))], "marker 0.position: three numbers"),
        ([Marker((0, 0, 1), colour=(0, 0, 255))], "marker 0.colour: red, green and blue in"),
        ([Marker((0, 0, 1), label="tip\n")], "marker 0.label: at most 32 printable ASCII"),
        ([Marker((0, 0, 1), label="x" * 33)], "marker 0.label: at most 32"),
        ([Marker((0, 0, 1))] * (MAX_MARKERS + 1), "at most 16 points, got 17"),
        (Marker((0, 0, 1)), "a list of Marker, got Marker"),
    ],
)
def test_a_marker_that_is_not_allowed_is_named(
    hostile_env, monkeypatch: pytest.MonkeyPatch, marked: Any, named: str
) -> None:
    monkeypatch.setattr(HostileTask, "marked", marked)
    hostile_env.reset(seed=0)
    with pytest.raises(ValueError) as raised:
        hostile_env.render_image()
    assert named in str(raised.value)


def test_a_marker_is_drawn_where_the_camera_sees_its_point(
    hostile_env, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A marked point's pixel has the marker's colour where an unmarked picture of the same
    camera shows the ground or the sky; the camera projects each link's centre onto that
    link's (coloured) pixels, and a point behind the camera is not drawn."""
    env = hostile_env
    env.reset(seed=0)
    point = Marker((0.3, -0.2, 0.4), colour=(1.0, 0.0, 1.0), label="target")
    monkeypatch.setattr(HostileTask, "marked", [point])
    camera, markers = env.camera()
    assert markers == [point]
    plain = env.sim.render(camera)
    marked = env.render_image()
    u, v = (round(value) for value in camera.pixel(point.position))
    assert 0 <= u < camera.width and 0 <= v < camera.height
    assert np.ptp(plain[v, u].astype(int)) < GROUND_AND_SKY  # ground or sky
    assert tuple(marked[v, u]) == (255, 0, 255)
    changed = np.argwhere((marked != plain).any(axis=2))
    assert len(changed) > 50  # the dot and its label
    assert np.abs(changed - [v, u]).max() < 60  # ... and nothing far from it

    snapshot = env.snapshot()
    for k in range(len(env.robot.link_names)):
        column, row = (round(value) for value in camera.pixel(snapshot.centre(k)))
        assert np.ptp(plain[row, column].astype(int)) > GROUND_AND_SKY, env.robot.link_names[k]

    looked_at, _ = env.robot.camera(snapshot, [point.position])
    eye = np.linalg.inv(np.reshape(camera.view, (4, 4), order="F"))[:3, 3]
    behind = Marker(tuple((2 * eye - looked_at).tolist()), colour=(0.0, 1.0, 1.0))
    assert camera.pixel(behind.position) is None
    assert (draw_markers(plain, camera, [behind]) == plain).all()


def test_diagonal_gesture_reports_its_angle_and_marks_its_target(env_of) -> None:
    env = env_of("diagonal-gesture", "crossed_chain")
    try:
        episodes = evaluate_policy(env, _hold(env), [3, 4])
        camera, markers = env.camera()
        plain = env.sim.render(camera)
        image = env.render_image()
    finally:
        env.close()
    for episode in episodes:
        # Its last step's cosine with the diagonal, as an angle.
        angle = math.degrees(math.acos(episode.metric[-1]))
        assert episode.task_metrics == {"angle_deg": pytest.approx(angle)}
    assert episodes[0].task_metrics["angle_deg"] == pytest.approx(54.7, abs=1.0)  # upright
    [target] = markers
    assert target.label == "target"
    # Held upright, c's parent end is at a's and b's lengths (0.4 m each) above the ground:
    # the target is c's length (0.4 m) on, along the diagonal.
    expected = np.array([0.0, 0.0, 0.8]) + 0.4 * np.ones(3) / math.sqrt(3)
    assert target.position == pytest.approx(tuple(expected), abs=0.01)
    u, v = (round(value) for value in camera.pixel(target.position))
    assert tuple(image[v, u]) == target.rgb() != tuple(plain[v, u])


def test_what_docs_plugins_md_says_of_a_tasks_hooks_and_markers_is_so() -> None:
    """Every hook the hook table of docs/plugins.md names is a Task method, and the
    limits its task metrics and markers table states are the code's."""
    import dataclasses
    import re
    from pathlib import Path

    from adworker import task_metrics

    docs = (Path(__file__).resolve().parents[2] / "docs" / "plugins.md").read_text()
    hooks_table = docs[docs.index("| hook | default |") :]
    hooks_table = hooks_table[: hooks_table.index("\n\n")]
    hooks = set(re.findall(r"^\| `(\w+)\(", hooks_table, re.MULTILINE))
    assert {"metric", "reward", "score", "metrics", "markers"} <= hooks
    for hook in hooks:
        assert callable(getattr(Task, hook, None)), hook

    own = docs[docs.index("**Metrics and marks of its own.**") :]
    own = own[: own.index("An environment of another")]
    assert f"`{task_metrics.TASK_METRIC_NAME.pattern}`" in own
    assert f"at most {MAX_TASK_METRICS} names" in own
    assert f"At most {MAX_MARKERS};" in own
    assert "`task.<name>`" in own and task_metrics.TASK_METRIC_PREFIX == "task."
    fields = re.search(r"`Marker\((\w+), (\w+), (\w+)\)`", own)
    assert fields is not None
    assert list(fields.groups()) == [field.name for field in dataclasses.fields(Marker)]
    # The messages it quotes are the code's.
    for values, quoted in [
        ({"tip distance": 1.0}, "task metric name 'tip distance' must match"),
        ({"tip_distance": math.nan}, "task metric 'tip_distance' must be finite, got nan"),
    ]:
        assert f"`{quoted}" in own
        with pytest.raises(ValueError) as raised:
            checked_task_metrics(values)
        assert str(raised.value).startswith(quoted)
    quoted = "marker 1.position: numbers must be finite, got nan"
    assert f"`{quoted}`" in own
    with pytest.raises(ValueError, match=f"^{re.escape(quoted)}$"):
        checked_markers([Marker((0, 0, 1)), Marker((0, math.nan, 1))])


def test_labels_of_markers_close_together_do_not_overlap() -> None:
    """Two marked points a few pixels apart (a tip on its target) and a third beside
    them: each label is drawn where it covers no other label and no other dot, inside
    the picture; on a blank picture, each label's pixels are where its box says."""
    flat = tuple(np.eye(4).flatten(order="F").tolist())
    camera = Camera(view=flat, projection=flat, width=200, height=200)
    markers = [
        Marker((0.0, 0.0, 0.0), colour=(0.0, 0.8, 0.0), label="target"),
        Marker((0.04, 0.0, 0.0), colour=(0.0, 0.0, 1.0), label="tip"),
        Marker((0.16, 0.0, 0.0), colour=(1.0, 0.0, 0.0), label="elbow"),
        Marker((0.98, 0.0, 0.0), colour=(1.0, 0.0, 1.0), label="by the edge"),
    ]
    pixels = [camera.pixel(marker.position) for marker in markers]
    dots = [
        (round(u) - DOT_RADIUS, round(v) - DOT_RADIUS, round(u) + DOT_RADIUS, round(v) + DOT_RADIUS)
        for u, v in pixels
    ]
    sizes = [(6 * len(marker.label), 11) for marker in markers]
    boxes = label_places(dots, sizes, (camera.width, camera.height))
    for index, box in enumerate(boxes):
        assert box is not None
        assert box[0] >= 0 and box[2] <= camera.width and box[1] >= 0 and box[3] <= camera.height
        others = [dot for k, dot in enumerate(dots) if k != index] + [
            other for k, other in enumerate(boxes) if k != index
        ]
        for other in others:
            assert _shared(box, other) == 0, (markers[index].label, box, other)
    assert label_places(dots[:1], [None], (200, 200)) == [None]

    blank = np.full((200, 200, 3), 255, dtype=np.uint8)
    drawn = draw_markers(blank, camera, markers)
    dark = np.argwhere((drawn < 60).all(axis=2))  # the rims and the labels' text
    assert len(dark) > 100
    inside_some = [
        any(
            left - 1 <= x <= right + 1 and top - 1 <= y <= bottom + 1
            for left, top, right, bottom in dots
        )
        for y, x in dark
    ]
    assert not all(inside_some)  # the labels are drawn, beside the dots


def _shared(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> int:
    width = min(a[2], b[2]) - max(a[0], b[0])
    height = min(a[3], b[3]) - max(a[1], b[1])
    return max(width, 0) * max(height, 0)
