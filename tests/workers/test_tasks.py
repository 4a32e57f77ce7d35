"""The task environments: Gymnasium conformance, determinism, and what they measure."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from adworker import designs
from tests.workers.robots import example_study

BUILT_IN = ["diagonal-gesture", "lift-highest", "stand-up", "walk-forward"]


@pytest.mark.parametrize("task", BUILT_IN)
def test_env_checker_passes(task: str, env_of) -> None:
    env = env_of(task, "crossed_chain")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            warnings.filterwarnings("ignore", message=".*infinity.*")
            warnings.filterwarnings("ignore", message=".*not having a spec.*")
            check_env(env)
    finally:
        env.close()


def test_a_task_class_whose_base_its_declaration_contradicts_builds_no_env(tmp_path) -> None:
    """The server says where a robot starts by the task's declaration
    (``TaskSpec.fixed_base``): a class that would put it elsewhere is refused."""
    from adclient.builtin_tasks import DIAGONAL_GESTURE, DiagonalGestureOptions
    from adworker.tasks.diagonal_gesture import DiagonalGesture
    from tests.workers.robots import write_urdf

    class Unfixed(DiagonalGesture):
        fixed_base = False

    assert DIAGONAL_GESTURE.fixed_base is DiagonalGesture.fixed_base is True
    design = designs.crossed_chain()
    urdf_path = write_urdf(design, tmp_path / "robot.urdf")
    with pytest.raises(ValueError, match="its class has fixed_base = False, its declaration"):
        Unfixed.make_env(design=design, urdf_path=urdf_path, options=DiagonalGestureOptions())


def test_close_disconnects_and_envs_do_not_share_a_client(env_of) -> None:
    import pybullet

    first = env_of("stand-up", "arch_chain")
    second = env_of("stand-up", "arch_chain")
    first_client = first.sim.client
    assert first_client != second.sim.client
    assert pybullet.isConnected(physicsClientId=first_client)
    first.close()
    assert not pybullet.isConnected(physicsClientId=first_client)
    second.reset(seed=0)
    second.step(np.zeros(2, dtype=np.float32))
    second.close()


def _trace(env, action, seed: int) -> list[float]:
    env.reset(seed=seed)
    for _ in range(env.episode_steps):
        env.step(np.asarray(action, dtype=np.float32))
    return list(env.record.metric)


@pytest.mark.parametrize("task", BUILT_IN)
def test_episodes_depend_only_on_seed_and_policy(task: str, env_of) -> None:
    env = env_of(task, "arch_chain")
    try:
        first = _trace(env, [0.4, 0.4], seed=7)
        _trace(env, [-1.0, 1.0], seed=3)  # something else in between
        again = _trace(env, [0.4, 0.4], seed=7)
        other_seed = _trace(env, [0.4, 0.4], seed=8)
    finally:
        env.close()
    assert first == again
    assert first != other_seed


def test_stand_up_arch_lifts_b_and_along_links_cannot(env_of) -> None:
    action = [0.7, 0.7]  # both joints bent ~63 degrees, the same way: an arch
    arch = env_of("stand-up", "arch_chain")
    along = env_of("stand-up", "along_links_chain")
    try:
        _trace(arch, action, seed=0)
        arch_score = arch.record.score()
        snapshot = arch.snapshot()
        a, c = arch.robot.link_index("a"), arch.robot.link_index("c")
        assert snapshot.touching[a] and snapshot.touching[c]
        along_scores = []
        for candidate in ([0.7, 0.7], [-0.7, -0.7], [1.0, -1.0], [0.0, 0.0]):
            _trace(along, candidate, seed=0)
            along_scores.append(along.record.score())
    finally:
        arch.close()
        along.close()
    radius = 0.04
    assert arch_score > 0.3  # b's centre well off the ground
    assert max(along_scores) < radius + 0.01  # b stays lying at its radius


def test_stand_up_counts_zero_while_a_foot_is_off_the_ground(env_of) -> None:
    env = env_of("stand-up", "arch_chain")
    try:
        # Bent the other way the chain lies on b with a and c in the air (a "U").
        _trace(env, [-0.5, -0.5], seed=0)
        metric = env.record.metric
        snapshot = env.snapshot()
    finally:
        env.close()
    assert not (snapshot.touching[0] and snapshot.touching[2])
    assert metric[-1] == 0.0


def test_diagonal_gesture_crossed_axes_reach_the_diagonal_parallel_ones_cannot(env_of) -> None:
    crossed = env_of("diagonal-gesture", "crossed_chain")
    parallel = env_of("diagonal-gesture", "parallel_chain")
    try:
        grid = np.linspace(-1, 1, 9)
        crossed_best = max(_score(crossed, [u, v]) for u in grid for v in grid)
        parallel_best = max(_score(parallel, [u, v]) for u in grid for v in grid)
    finally:
        crossed.close()
        parallel.close()
    # Parallel axes along x keep c in the y-z plane: at best cos = sqrt(2/3).
    assert parallel_best <= math.sqrt(2 / 3) + 0.01
    assert crossed_best > 0.95


def _score(env, action) -> float:
    _trace(env, action, seed=0)
    return env.record.score()


def test_lift_highest_works_on_a_branching_tree(env_of) -> None:
    star = designs.tree_design(
        [("a", "b"), ("a", "c"), ("a", "d")],
        {"b": (math.pi / 2, math.pi / 2), "c": (math.pi / 2, 0.0), "d": (0.0, 0.0)},
        position={"b": 1.0, "c": 0.5, "d": 1.0},
    )
    env = env_of("lift-highest", star)
    try:
        assert env.action_space.shape == (3,)
        rest = _score(env, [0.0, 0.0, 0.0])
        raised = max(_score(env, [u, v, 0.0]) for u in (-1, 1) for v in (-1, 1))
    finally:
        env.close()
    assert rest == pytest.approx(0.08, abs=0.01)  # lying flat: top of a cylinder of radius 0.04
    assert raised > rest + 0.1


def test_render_image_is_a_picture_of_the_robot(env_of) -> None:
    env = env_of("stand-up", "arch_chain", render_mode="rgb_array")
    try:
        env.reset(seed=0)
        image = env.render()
    finally:
        env.close()
    assert image is not None
    assert image.shape == (240, 320, 3)
    assert image.dtype == np.uint8
    assert len(np.unique(image.reshape(-1, 3), axis=0)) > 10  # not a blank frame


# ------------------------------------------------------------ secondary metrics


def _engine_masses(env) -> list[float]:
    import pybullet

    cid, body = env.sim.client, env.robot.body
    count = pybullet.getNumJoints(body, physicsClientId=cid)
    return [
        pybullet.getDynamicsInfo(body, link, physicsClientId=cid)[0] for link in range(-1, count)
    ]


def test_design_mass_is_the_mass_pybullet_simulates(env_of) -> None:
    from adclient.urdf import design_link_length, design_mass

    star = designs.tree_design(
        [("a", "b"), ("a", "c"), ("a", "d")],
        {"b": (math.pi / 2, math.pi / 2), "c": (math.pi / 2, 0.0), "d": (0.0, 0.0)},
        length={"a": 0.3, "b": 0.45, "c": 0.25, "d": 0.5},
        mass=0.7,
    )
    star.links[2].mass = 1.9  # one link heavier than the others
    for task, design in (("lift-highest", star), ("stand-up", designs.arch_chain(mass=0.8))):
        env = env_of(task, design)
        try:
            engine = _engine_masses(env)
        finally:
            env.close()
        assert len(engine) == len(design.links)
        assert design_mass(design) == pytest.approx(math.fsum(engine), rel=1e-12)
    # A fixed base is static in the engine (it reports mass 0 for it): the robot as built
    # still has that link, and its mass counts; the moving links' are the engine's.
    arm = designs.arch_chain(mass=0.8)
    env = env_of("diagonal-gesture", arm)
    try:
        base, *moving = _engine_masses(env)
    finally:
        env.close()
    assert base == 0.0
    assert design_mass(arm) == pytest.approx(0.8 + math.fsum(moving), rel=1e-12)
    assert design_mass(star) == pytest.approx(3 * 0.7 + 1.9)
    assert design_link_length(star) == pytest.approx(0.3 + 0.45 + 0.25 + 0.5)


def test_mass_follows_the_mass_specs_and_link_length_the_lengths(env_of) -> None:
    """A link of a part that gives ``mass`` weighs that spec (written as the URDF's
    inertial mass), whatever its size: heavier links make a heavier robot; longer or
    thicker ones, of the same mass spec, a longer one of the same mass. (A part that gives
    ``density`` instead: the next test.)"""
    from adclient.urdf import design_link_length, design_mass

    base = designs.arch_chain()
    heavier = designs.arch_chain(mass=1.5)
    bigger = designs.arch_chain(length=0.55, radius=0.06)
    assert design_mass(heavier) > design_mass(base) == pytest.approx(3.0)
    assert design_mass(bigger) == design_mass(base)
    assert design_link_length(bigger) > design_link_length(base) == pytest.approx(1.2)
    for design in (heavier, bigger):
        env = env_of("stand-up", design)
        try:
            assert math.fsum(_engine_masses(env)) == pytest.approx(design_mass(design))
        finally:
            env.close()


def test_a_density_links_mass_is_what_pybullet_simulates(env_of) -> None:
    """examples/score-vs-mass.yaml's aluminium links (density 2700 kg/m^3): PyBullet's
    mass of each link is density x pi r^2 x length, its inertia that of a solid cylinder
    of that mass, and the worker's ``mass`` metric their sum: longer or thicker links
    weigh more."""
    import pybullet

    from adclient.decode import decode, identity_representation
    from adworker.evaluate import design_metrics

    study = example_study("score-vs-mass")
    space = study.space
    representation = identity_representation(space)
    size = len(representation.spec_names)
    masses = []
    for u in (0.0, 0.37, 1.0):
        design = decode(space, representation, [u] * size)
        env = env_of("stand-up", design)
        try:
            cid, body = env.sim.client, env.robot.body
            index = {design.root: -1}
            for joint in range(pybullet.getNumJoints(body, physicsClientId=cid)):
                info = pybullet.getJointInfo(body, joint, physicsClientId=cid)
                index[info[12].decode()] = joint
            engine = []
            for link in design.links:
                dynamics = pybullet.getDynamicsInfo(body, index[link.name], physicsClientId=cid)
                volume = math.pi * link.radius**2 * link.length
                assert link.density == 2700.0
                assert dynamics[0] == pytest.approx(2700.0 * volume, rel=1e-12)
                r, h, m = link.radius, link.length, dynamics[0]
                ixx, izz = m * (3 * r * r + h * h) / 12, m * r * r / 2
                assert dynamics[2] == pytest.approx((ixx, ixx, izz), rel=1e-6)
                engine.append(dynamics[0])
        finally:
            env.close()
        metrics = design_metrics(design)
        assert metrics["mass"] == pytest.approx(math.fsum(engine), rel=1e-12)
        masses.append(metrics["mass"])
    assert masses[0] == pytest.approx(3 * 2700.0 * math.pi * 0.01**2 * 0.25, rel=1e-12)
    assert masses[2] == pytest.approx(3 * 2700.0 * math.pi * 0.03**2 * 0.6, rel=1e-12)
    assert masses[0] < masses[1] < masses[2]


def _metered(env, action, seeds=(0, 1)):
    meter = env.meter_motors()
    for seed in seeds:
        _trace(env, action, seed)
    return meter


@pytest.mark.parametrize("task", BUILT_IN)
def test_motors_resting_in_their_target_pose_cost_nothing_and_moving_costs(
    task: str, env_of
) -> None:
    """Zero action is the rest pose (limits symmetric about 0). Started exactly there
    (no initial perturbation), a lying robot rests on the ground and an upright fixed one
    holds its weight along the joints' axes: no torque, no work, up to the contact
    solver's residue on the ground (0.02 N m, a thousandth of the motors' 20). Bending
    the joints costs both; the torque never exceeds the joints' effort limit."""
    env = env_of(task, "arch_chain", init_noise=0.0)
    try:
        rest = _metered(env, [0.0, 0.0])
        bent = _metered(env, [0.7, 0.7])
    finally:
        env.close()
    assert rest.samples == bent.samples == 2 * env.episode_steps * env.sim.frame_skip
    assert len(rest.episode_energy) == len(bent.episode_energy) == 2
    assert 0.0 <= rest.effort < 0.05
    assert 0.0 <= rest.energy < 1e-4
    if task == "diagonal-gesture":
        assert rest.effort == rest.energy == 0.0
    assert 1.0 < bent.effort <= 20.0
    assert bent.energy > 1.0
    assert min(bent.episode_energy) > 1.0


def test_holding_a_pose_against_gravity_costs_effort_but_no_energy(env_of) -> None:
    """An arm on a fixed upright base, both axes horizontal, b bent 45 degrees and c
    straight: once still, each motor applies the static torque of the weight beyond it
    (m g times the horizontal lever of each link's centre) and does no work."""
    env = env_of("diagonal-gesture", "parallel_chain", init_noise=0.0, episode_steps=64)
    try:
        meter = env.meter_motors()
        env.reset(seed=0)
        action = np.array([0.5, 0.0], dtype=np.float32)  # q_b = pi/4, q_c = 0
        for _ in range(40):
            env.step(action)
        torque, energy, samples = meter.torque_sum, meter.episode_energy[-1], meter.samples
        for _ in range(24):
            env.step(action)
    finally:
        env.close()
    g, length, mass, lean = 9.81, 0.4, 1.0, math.sin(math.pi / 4)
    at_b = g * mass * (length / 2 + 3 * length / 2) * lean  # b's and c's centres
    at_c = g * mass * (length / 2) * lean
    held = (meter.torque_sum - torque) / ((meter.samples - samples) * 2)
    assert held == pytest.approx((at_b + at_c) / 2, rel=1e-3)
    assert meter.episode_energy[-1] - energy < 1e-6
    assert meter.energy > 1.0  # getting there did cost


def test_metering_does_not_change_an_episode(env_of) -> None:
    env = env_of("walk-forward", "arch_chain")
    try:
        plain = _trace(env, [0.4, -0.6], seed=3)
        env.meter_motors()
        metered = _trace(env, [0.4, -0.6], seed=3)
    finally:
        env.close()
    assert metered == plain
