"""One simulator interface, two engines (issue 59): every built-in task on PyBullet and on
MuJoCo, real engines both. The same design has the same spaces, links and metrics on
either; what scores badly on PyBullet (a fall, a dive, a link pushed into the ground)
scores badly on MuJoCo; and stand-up and lift-highest rank clearly different designs in
the same order on both (the ``fast`` learner's best pose, as the worker scores it)."""

from __future__ import annotations

import itertools
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from adclient.designs import Design
from adclient.plugins import SIMULATORS, catalogue
from adworker import designs
from adworker.learners import evaluate_policy
from adworker.tasks.base import robot_model
from adworker.tasks.build import build_engine
from tests.workers.robots import HALF_PI, make_job, write_urdf

ENGINES = ("pybullet", "mujoco")


@pytest.fixture
def engine_env(tmp_path: Path):
    """An installed task's env of a design on an engine, built as the worker builds it."""
    numbers = itertools.count()
    built: list[Any] = []

    def make(task: str, design: Design | str, simulator: str, **options: object) -> Any:
        robot = getattr(designs, design)() if isinstance(design, str) else design
        urdf_path = write_urdf(robot, tmp_path / f"robot-{next(numbers)}.urdf")
        spec = catalogue().task(task)
        env = spec.load_factory()(
            design=robot,
            urdf_path=urdf_path,
            options=spec.options.model_validate(options),
            simulator=simulator,
        )
        built.append(env)
        return env

    yield make
    for env in built:
        env.close()


def quadruped() -> Design:
    """examples/quadruped.yaml's robot, its searched specs at mid-range, as a job
    decodes it."""
    from adworker.job_robots import decode_job

    specs = {
        "front_left.length": 0.2,
        "front_left_shin.length": 0.2,
        "front_left.joint.axis_theta": HALF_PI,
        "front_left.joint.axis_phi": HALF_PI,
        "front_left_shin.joint.axis_theta": HALF_PI,
        "front_left_shin.joint.axis_phi": HALF_PI,
    }
    return decode_job(make_job("quadruped", specs))


def star() -> Design:
    return designs.tree_design(
        [("a", "b"), ("a", "c"), ("a", "d")],
        {"b": (HALF_PI, HALF_PI), "c": (HALF_PI, 0.5), "d": (HALF_PI, 2.6)},
        length=0.4,
    )


def episode(env: Any, action: list[float], seed: int = 0) -> list[Any]:
    """One episode holding ``action``: its snapshots, the env's record holding its score."""
    env.reset(seed=seed)
    snapshots = []
    for _ in range(env.episode_steps):
        env.step(np.array(action, dtype=np.float32))
        snapshots.append(env.snapshot())
    return snapshots


SAME_DESIGNS = [
    ("stand-up", "arch_chain"),
    ("lift-highest", "star"),
    ("walk-forward", "quadruped"),
    ("diagonal-gesture", "crossed_chain"),
]


def design_of(name: str) -> Design:
    return {"star": star, "quadruped": quadruped}.get(name, getattr(designs, name, None))()


@pytest.mark.parametrize(("task", "design"), SAME_DESIGNS)
def test_a_design_has_the_same_spaces_links_and_metrics_on_both_engines(
    engine_env, task: str, design: str
) -> None:
    built = {engine: engine_env(task, design_of(design), engine) for engine in ENGINES}
    pybullet, mujoco = built["pybullet"], built["mujoco"]
    assert pybullet.observation_space == mujoco.observation_space
    assert pybullet.action_space == mujoco.action_space
    assert pybullet.robot.link_names == mujoco.robot.link_names
    assert [j.name for j in pybullet.robot.joints] == [j.name for j in mujoco.robot.joints]
    assert [g.mass for g in pybullet.robot.geometry] == pytest.approx(
        [g.mass for g in mujoco.robot.geometry]
    )
    assert pybullet.sim.control_period == mujoco.sim.control_period
    metrics = {}
    for engine, env in built.items():
        meter = env.meter_motors()
        first = env.reset(seed=3)[0]
        assert env.observation_space.contains(first)
        action = np.linspace(-0.6, 0.6, env.joint_count)
        for _ in range(env.episode_steps):
            observation, reward, _, _, _ = env.step(action)
            assert np.all(np.isfinite(observation)) and math.isfinite(reward)
        assert env.sim_steps == env.episode_steps * env.options.frame_skip
        assert meter.effort > 0 and meter.energy > 0  # the motors moved the joints
        metrics[engine] = env.task_metrics()
    assert metrics["pybullet"].keys() == metrics["mujoco"].keys()
    # the same spawn on both: the first observation's joint angles and heights agree
    starts = [env.reset(seed=5)[0] for env in built.values()]
    assert starts[0][: 2 * pybullet.joint_count] == pytest.approx(
        starts[1][: 2 * pybullet.joint_count], abs=1e-6
    )


@pytest.mark.parametrize("engine", ENGINES)
def test_an_episode_depends_only_on_its_seed_and_policy(engine_env, engine: str) -> None:
    env = engine_env("stand-up", "arch_chain", engine)
    first = [s.centre_z for s in episode(env, [0.7, 0.7], seed=1)]
    episode(env, [-1.0, 1.0], seed=2)
    again = [s.centre_z for s in episode(env, [0.7, 0.7], seed=1)]
    other = [s.centre_z for s in episode(env, [0.7, 0.7], seed=2)]
    assert first == again
    assert first != other


@pytest.mark.parametrize("engine", ENGINES)
def test_falls_dives_and_buried_links_score_badly_on_both_engines(engine_env, engine: str) -> None:
    radius = 0.04
    arch = engine_env("stand-up", "arch_chain", engine)
    lifted = episode(arch, [0.7, 0.7])
    assert arch.record.score() > 0.3  # the arch stands: b's centre well off the ground
    assert lifted[-1].touching[0] and lifted[-1].touching[2]
    # bent the other way it falls onto b, feet in the air: a lifted foot counts 0
    u_shape = episode(arch, [-0.5, -0.5])
    assert arch.record.score() == 0.0
    assert not (u_shape[-1].touching[0] and u_shape[-1].touching[2])
    # pushed hard into the ground no link goes through it (hides under the floor)
    for action in ([-1.0, -1.0], [1.0, -1.0], [1.0, 1.0]):
        for snapshot in episode(arch, action):
            assert min(snapshot.bottom) > -0.01, (action, snapshot.bottom)
    # axes along the links cannot lift b: it stays lying at its radius
    along = engine_env("stand-up", "along_links_chain", engine)
    for action in ([0.7, 0.7], [-0.7, -0.7], [1.0, -1.0]):
        episode(along, action)
        assert along.record.score() < radius + 0.01
    # a quadruped that throws its legs into one pose (a dive) and lies there has not
    # walked forward, and comes to rest
    walker = engine_env("walk-forward", quadruped(), engine)
    for action in (np.ones(walker.joint_count), -np.ones(walker.joint_count)):
        episode(walker, list(action))
        metric = walker.record.metric
        assert walker.record.score() < 0.05, metric
        assert abs(metric[-1] - metric[-8]) < 0.01, metric
    # a star lying flat holds nothing high: the top of a cylinder of radius 0.04
    flat = engine_env("lift-highest", star(), engine)
    episode(flat, [0.0, 0.0, 0.0])
    assert flat.record.score() == pytest.approx(2 * radius, abs=0.01)


def fast_score(env: Any, seed: int = 0) -> float:
    """The worker's score of a design with the ``fast`` learner, trained and evaluated on
    ``env`` (three evaluation episodes)."""
    learner = catalogue().learner("fast").load_factory()(None)
    trained = learner.train(env, steps=1024, seed=seed)
    episodes = evaluate_policy(env, trained.policy, [1000 + seed + i for i in range(3)])
    return float(np.mean([result.score for result in episodes]))


RANKED = {
    "stand-up": [
        (
            "arch 0.55",
            designs.tree_design(
                [("a", "b"), ("b", "c")],
                {"b": (HALF_PI, HALF_PI), "c": (HALF_PI, HALF_PI)},
                length=0.55,
            ),
        ),
        ("arch 0.40", designs.arch_chain()),
        (
            "arch 0.30",
            designs.tree_design(
                [("a", "b"), ("b", "c")],
                {"b": (HALF_PI, HALF_PI), "c": (HALF_PI, HALF_PI)},
                length=0.3,
            ),
        ),
        ("along the links", designs.along_links_chain()),
    ],
    "lift-highest": [
        (
            "chain of 4",
            designs.tree_design(
                [("a", "b"), ("b", "c"), ("c", "d")],
                {"b": (HALF_PI, HALF_PI), "c": (HALF_PI, HALF_PI), "d": (HALF_PI, 0.0)},
                length=0.4,
            ),
        ),
        ("chain of 3", designs.arch_chain()),
        (
            "short chain of 3",
            designs.tree_design(
                [("a", "b"), ("b", "c")],
                {"b": (HALF_PI, HALF_PI), "c": (HALF_PI, HALF_PI)},
                length=0.2,
            ),
        ),
        ("along the links", designs.along_links_chain()),
    ],
}
"""Designs that differ clearly in what they can do, each task's best first (by
construction: longer arches stand higher; a chain of axes along its links only rolls)."""


@pytest.mark.slow
@pytest.mark.parametrize("task", sorted(RANKED))
def test_stand_up_and_lift_highest_rank_clear_designs_alike_on_both_engines(
    engine_env, task: str
) -> None:
    scores = {
        engine: [fast_score(engine_env(task, design, engine)) for _, design in RANKED[task]]
        for engine in ENGINES
    }
    names = [name for name, _ in RANKED[task]]
    for engine, values in scores.items():
        # each engine ranks them as constructed, with a clear gap between neighbours
        order = [names[k] for k in np.argsort(values)[::-1]]
        assert order == names, (engine, dict(zip(names, values, strict=True)))
    pybullet, mujoco = np.array(scores["pybullet"]), np.array(scores["mujoco"])
    # and scores the same quantity, design by design: within 2 cm, or MuJoCo's between
    # 0.6 and 1.25 of PyBullet's (its arch of 0.55 m links holds b at about 0.41 m where
    # PyBullet's holds 0.55: a difference of the engines' contacts and servos, measured
    # in bench/RESULTS.md, "Engines", not yet explained)
    close = np.abs(pybullet - mujoco) <= 0.02
    assert np.all(close | ((mujoco >= 0.6 * pybullet) & (mujoco <= 1.25 * pybullet))), scores


def test_an_engine_that_is_not_one_is_refused_naming_the_engines(tmp_path: Path) -> None:
    design = designs.arch_chain()
    urdf_path = write_urdf(design, tmp_path / "robot.urdf")
    with pytest.raises(ValueError, match="'bogus' is not one \\(pybullet, mujoco\\)"):
        build_engine(
            "bogus",
            model=robot_model(design, urdf_path),
            urdf_path=urdf_path,
            fixed_base=False,
            reads_contacts=True,
            time_step=1 / 120,
            frame_skip=12,
            rolling_friction=0.02,
            spinning_friction=0.0,
        )
    assert SIMULATORS == ENGINES


@pytest.mark.parametrize("engine", ENGINES)
def test_a_picture_of_the_robot_on_either_engine(engine_env, engine: str) -> None:
    env = engine_env("diagonal-gesture", "crossed_chain", engine)
    episode(env, [0.6, -0.4])
    image = env.render_image()
    assert image.shape == (240, 320, 3) and image.dtype == np.uint8
    # the robot is in it: colours other than the ground's grey and the sky's white
    coloured = np.abs(image.astype(int) - image.mean(axis=2, keepdims=True)).max(axis=2) > 40
    assert coloured.sum() > 200


UNSTABLE_URDF = """<robot name="unstable">
<link name="a"><inertial><mass value="1"/>
<inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
<collision><geometry><box size="0.2 0.2 0.2"/></geometry></collision></link>
<link name="b"><inertial><mass value="0.0001"/>
<inertia ixx="1e-10" iyy="1e-10" izz="1e-10" ixy="0" ixz="0" iyz="0"/></inertial>
<collision><origin xyz="0.1 0 0"/><geometry><box size="0.2 0.02 0.02"/></geometry></collision>
</link>
<joint name="j" type="revolute"><parent link="a"/><child link="b"/><origin xyz="0.1 0 0"/>
<axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="10000000" velocity="1000"/></joint>
</robot>"""


def test_a_design_that_diverges_on_mujoco_ends_its_episode_naming_it_and_writes_no_log(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A 0.1 g link on a 10 MN joint: MuJoCo's acceleration blows up and it resets the
    world to its rest pose, which would score a fresh start. The episode ends there with
    the reason, and MuJoCo's warning goes to the log, not to MUJOCO_LOG.TXT in the
    worker's folder."""
    from adworker.tasks.mujoco_engine import SimulationDiverged

    monkeypatch.chdir(tmp_path)
    urdf = tmp_path / "unstable.urdf"
    urdf.write_text(UNSTABLE_URDF)
    spec = catalogue().task("lift-highest")
    env = spec.load_factory()(
        design=None, urdf_path=urdf, options=spec.options.model_validate({}), simulator="mujoco"
    )
    try:
        env.reset(seed=0)
        with pytest.raises(SimulationDiverged, match="MuJoCo simulation diverged"):
            for step in range(env.episode_steps):
                env.step(np.full(env.action_space.shape, 1.0 if step % 2 else -1.0))
    finally:
        env.close()
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()
