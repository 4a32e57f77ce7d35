"""The MuJoCo example plugin (examples/mujoco-plugin): its model is the design, its env
trains with adworker's learners, and, really pip-installed into a folder only the
spawned processes see, it runs a managed study end to end with a real adserver and
adworker while a worker without it leaves its trials alone."""

from __future__ import annotations

import json
import math
import os
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest
import yaml

from adclient import Client
from adclient.designs import Design
from adclient.errors import Invalid
from adclient.testing.servers import ServerProcess
from adclient.testing.workers import PATIENCE, WorkerProcess, pip_install_target, plugin_path
from adclient.urdf import design_to_urdf, link_inertia
from adworker import designs
from adworker.constant_search import ConstantTargetSearch
from adworker.learners import evaluate_policy

# Off-screen rendering through EGL, chosen before MuJoCo is first imported (the
# plugin does the same in the worker).
os.environ.setdefault("MUJOCO_GL", "egl")
try:
    import mujoco
except ImportError as error:  # the dev extra installs it: `make install`
    pytest.skip(
        f"MUJOCO IS NOT INSTALLED ({error}): the MuJoCo example plugin is not tested; "
        "`make install` (pip install -e '.[dev]') installs it",
        allow_module_level=True,
    )

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
PLUGIN = EXAMPLES / "mujoco-plugin"


@pytest.fixture
def plugin(monkeypatch: pytest.MonkeyPatch) -> Iterator[tuple[ModuleType, ModuleType]]:
    """The plugin's modules imported from its source folder (no dist-info there, so the
    catalogue of this process stays as it is); (mjcf, env)."""
    monkeypatch.syspath_prepend(str(PLUGIN))
    import adplugin_mujoco.env
    import adplugin_mujoco.mjcf

    yield adplugin_mujoco.mjcf, adplugin_mujoco.env
    for name in [name for name in sys.modules if name.startswith("adplugin_mujoco")]:
        del sys.modules[name]


def a_tree() -> Design:
    """A branching tree with joints part way along their parents, a box link, and a joint
    without limits (lower == upper: it turns all the way round)."""
    design = designs.tree_design(
        [("a", "b"), ("b", "c"), ("b", "d")],
        {"b": (0.7, 0.3), "c": (math.pi / 2, 2.0), "d": (2.5, 1.1)},
        length={"a": 0.3, "b": 0.5, "c": 0.25, "d": 0.4},
        position={"b": 1.0, "c": 0.6, "d": 1.0},
    )
    design.links[1] = design.links[1].model_copy(update={"shape": "box", "radius": 0.05})
    design.links[2] = design.links[2].model_copy(update={"mass": 0.4})
    design.joints[2] = design.joints[2].model_copy(update={"lower": 0.0, "upper": 0.0})
    return design


def a_tree_of_kinds() -> Design:
    """a_tree with a sliding, an all-round and a welded joint, each turned on its parent
    (issue 28)."""
    design = a_tree()
    kinds = [
        {"kind": "prismatic", "lower": 0.0, "upper": 0.3, "offset_roll": 0.4, "offset_yaw": 0.7},
        {"kind": "continuous", "lower": -math.pi, "upper": math.pi, "offset_pitch": -0.9},
        {"kind": "fixed", "offset_roll": 1.1, "offset_pitch": 0.2, "offset_yaw": -0.5},
    ]
    design.joints = [
        joint.model_copy(update=kind) for joint, kind in zip(design.joints, kinds, strict=True)
    ]
    return design


@pytest.mark.parametrize(
    "design", [a_tree(), a_tree_of_kinds(), designs.crossed_chain(), designs.arch_chain()]
)
def test_the_mujoco_model_is_the_design(
    plugin: tuple[ModuleType, ModuleType], design: Design, tmp_path: Path
) -> None:
    """Every link's frame, at random joint angles, where PyBullet puts it from the URDF
    the worker writes; each link's mass and inertia those of its shape."""
    import pybullet

    mjcf, _ = plugin
    model = mujoco.MjModel.from_xml_string(mjcf.design_to_mjcf(design))
    data = mujoco.MjData(model)
    urdf = tmp_path / "robot.urdf"
    urdf.write_text(design_to_urdf(design))
    client = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(str(urdf), useFixedBase=True, physicsClientId=client)
        index = {
            pybullet.getJointInfo(body, j, physicsClientId=client)[1].decode(): j
            for j in range(pybullet.getNumJoints(body, physicsClientId=client))
        }
        rng = np.random.default_rng(0)
        driven = [joint for joint in design.joints if joint.kind != "fixed"]
        for _ in range(5):
            for joint in driven:  # an angle, or a slide's metres
                angle = float(
                    rng.uniform(-math.pi, math.pi) / (10 if joint.kind == "prismatic" else 1)
                )
                data.qpos[model.joint(joint.name).qposadr[0]] = angle
                pybullet.resetJointState(body, index[joint.name], angle, physicsClientId=client)
            mujoco.mj_kinematics(model, data)
            for joint in design.joints:
                state = pybullet.getLinkState(
                    body, index[joint.name], computeForwardKinematics=1, physicsClientId=client
                )
                frame = data.body(joint.child)
                # The URDF link frame (not the inertial one): positions and rotations.
                assert frame.xpos == pytest.approx(state[4], abs=1e-6)
                rotation = np.reshape(pybullet.getMatrixFromQuaternion(state[5]), (3, 3))
                assert frame.xmat.reshape(3, 3) == pytest.approx(rotation, abs=1e-6)
    finally:
        pybullet.disconnect(client)
    assert data.body(design.root).xpos == pytest.approx([0, 0, 0])
    for link in design.links:
        frame = model.body(link.name)
        assert frame.mass[0] == pytest.approx(link.mass)
        assert frame.ipos == pytest.approx([0, 0, link.length / 2])
        assert sorted(frame.inertia) == pytest.approx(sorted(link_inertia(link)), rel=1e-6)
    assert model.njnt == len(driven)  # a fixed joint welds its child on
    for joint in driven:
        hinge = model.joint(joint.name)
        kind = (
            mujoco.mjtJoint.mjJNT_SLIDE
            if joint.kind == "prismatic"
            else mujoco.mjtJoint.mjJNT_HINGE
        )
        assert hinge.type[0] == kind
        assert hinge.axis == pytest.approx(np.array(joint.axis) / np.linalg.norm(joint.axis))
        limited = joint.lower < joint.upper and joint.kind != "continuous"
        assert bool(hinge.limited[0]) == limited
        if limited:
            assert hinge.range == pytest.approx([joint.lower, joint.upper])
        servo = model.actuator(driven.index(joint))
        assert servo.forcerange == pytest.approx([-joint.effort, joint.effort])


def test_the_env_trains_with_adworker_learners_and_tells_designs_apart(
    plugin: tuple[ModuleType, ModuleType],
) -> None:
    from adplugin_mujoco import MujocoReachOptions
    from gymnasium.utils.env_checker import check_env

    _, env_module = plugin
    scores = {}
    for name in ("crossed_chain", "parallel_chain", "along_links_chain"):
        env = env_module.MujocoReach(
            design=getattr(designs, name)(), urdf_path="unused", options=MujocoReachOptions()
        )
        trained = ConstantTargetSearch().train(env, steps=env.episode_steps * 12, seed=0)
        (episode,) = evaluate_policy(env, trained.policy, [1])
        scores[name] = episode.score
        assert env.sim_steps == 13 * env.episode_steps * env.options.frame_skip
        env.close()
    fresh = env_module.MujocoReach(
        design=designs.crossed_chain(), urdf_path="unused", options=MujocoReachOptions()
    )
    check_env(fresh, skip_render_check=True)
    # Axes across the links reach towards the target; along them, the arm only rolls
    # and its tip stays straight above the base.
    straight_up = -math.dist((0, 0, 1.2), (0.3, 0.3, 0.6))
    assert scores["along_links_chain"] == pytest.approx(straight_up, abs=0.01)
    assert scores["crossed_chain"] > scores["parallel_chain"] > scores["along_links_chain"]


def test_the_picture_shows_the_arm(plugin: tuple[ModuleType, ModuleType]) -> None:
    from adplugin_mujoco import MujocoReachOptions

    _, env_module = plugin
    try:
        mujoco.Renderer(mujoco.MjModel.from_xml_string("<mujoco/>"), 8, 8).close()
    except Exception as error:
        pytest.skip(
            f"MUJOCO CANNOT RENDER HERE ({error}): no EGL (Debian: libegl1 libegl-mesa0) or "
            "MUJOCO_GL; the plugin's pictures are blank, its scores are not affected"
        )
    env = env_module.MujocoReach(
        design=designs.crossed_chain(), urdf_path="unused", options=MujocoReachOptions()
    )
    env.reset(seed=0)
    image = env.render_image()
    env.close()
    assert image.shape == (240, 320, 3) and image.dtype == np.uint8
    # The links' colours: red (a), blue (b) and green (c) pixels, the target's red sphere.
    red, green, blue = (image[..., k].astype(int) for k in range(3))
    assert ((blue > red + 40) & (blue > green + 20)).sum() > 100, "b is not in the picture"
    assert ((green > red + 20) & (green > blue + 20)).sum() > 100, "c is not in the picture"


@pytest.fixture(scope="module")
def plugin_site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    site = pip_install_target(PLUGIN, tmp_path_factory.mktemp("mujoco-plugin"))
    assert (site / "adplugin_mujoco" / "env.py").is_file()
    return site


def reach_study() -> dict[str, Any]:
    """examples/mujoco-plugin/reach.yaml, three random designs, a small training budget."""
    body = yaml.safe_load((PLUGIN / "reach.yaml").read_text())
    body["proposer"] = {"name": "random", "seed": 1}
    body["task"].update(train_steps=32 * 8, eval_episodes=1)
    body["max_trials"] = 3
    return body


@pytest.mark.e2e
def test_a_mujoco_study_runs_end_to_end_and_only_workers_with_the_plugin_lease_it(
    plugin_site: Path, tmp_path: Path
) -> None:
    env = plugin_path(plugin_site)
    server = ServerProcess(
        database_url=f"sqlite:///{tmp_path / 'studies.db'}", workdir=tmp_path, env=env
    ).start()
    started: list[WorkerProcess] = []
    try:
        with Client(server.url) as client:
            assert "mujoco-reach" in {task.name for task in client.tasks()}
            # its plugin builds from a design: a template study of it is refused
            template = (EXAMPLES / "templates" / "arm.urdf.xacro").read_text()
            params = [{"name": "upper_length", "low": 0.1, "high": 0.5}]
            space = {"type": "template", "template": template, "params": params}
            with pytest.raises(Invalid, match="takes no template"):
                client.create_study({**reach_study(), "space": space})
            study = client.create_study(reach_study())

            without = WorkerProcess(server, tmp_path, "without", "--idle-exit", "3")
            started.append(without)
            assert without.wait() == 0, without.log()
            assert "mujoco-reach" not in without.log().split("tasks", 1)[1].splitlines()[0]
            assert client.study_info(study.id).n_trials == 0, "leased by a worker without it"

            with_it = WorkerProcess(server, tmp_path, "with", "--max-jobs", "3", env=env)
            started.append(with_it)
            assert with_it.wait() == 0, with_it.log()
            assert "'mujoco-reach'" in with_it.log().split("tasks", 1)[1].splitlines()[0]
            final = study.wait(poll=0.2, timeout=PATIENCE)
            assert final.n_complete == 3, [trial.message for trial in study.trials]
            values = [trial.value for trial in study.trials]
            for trial in study.trials:
                assert trial.worker_id == "with"
                assert trial.value is not None and math.isfinite(trial.value)
                # Minus a distance: the tip is within b + c <= 1 m of a's top, itself
                # 0.47 m from the target.
                assert -1.5 < trial.value < 0.0
                assert trial.metrics["sim_steps"] > 0
                names = {artifact.name for artifact in client.artifacts(trial)}
                assert names == {"robot.urdf", "robot.png", "curve.json"}
                # The env's own metric: the distance at the episode's last step.
                [episode] = json.loads(client.get_artifact(trial, "curve.json"))["evaluation"]
                distance = trial.metrics["task.tip_distance"]
                assert episode["task_metrics"] == {"tip_distance": distance}
                assert distance == pytest.approx(-episode["metric"][-1], abs=1e-6)
            assert len({round(value, 6) for value in values}) == 3, values
    finally:
        for worker in started:
            worker.stop()
        server.stop()
