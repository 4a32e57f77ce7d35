"""Test helper: write a hand-made Design as URDF.

Uses the SDK's writer (adclient.urdf) when it exists; until then a minimal writer
following the geometry conventions of adclient.design.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from adclient import Client
from adclient.client import StudyHandle
from adclient.designs import Design
from adclient.schemas import Trial
from adclient.testing.servers import ServerProcess
from adclient.testing.workers import WorkerProcess


def _fallback_urdf(design: Design, robot_name: str = "robot") -> str:
    lengths = {link.name: link.length for link in design.links}
    lines = [f'<robot name="{robot_name}">']
    for link in design.links:
        half = link.length / 2
        ixx = link.mass * (3 * link.radius**2 + link.length**2) / 12
        izz = link.mass * link.radius**2 / 2
        geometry = f'<cylinder length="{link.length}" radius="{link.radius}"/>'
        lines += [
            f'<link name="{link.name}">',
            f'<inertial><origin xyz="0 0 {half}"/><mass value="{link.mass}"/>'
            f'<inertia ixx="{ixx}" iyy="{ixx}" izz="{izz}" ixy="0" ixz="0" iyz="0"/></inertial>',
            f'<visual><origin xyz="0 0 {half}"/><geometry>{geometry}</geometry></visual>',
            f'<collision><origin xyz="0 0 {half}"/><geometry>{geometry}</geometry></collision>',
            "</link>",
        ]
    for joint in design.joints:
        z = joint.position * lengths[joint.parent]
        ax = " ".join(f"{v:.9f}" for v in joint.axis)
        lines += [
            f'<joint name="{joint.name}" type="revolute">',
            f'<parent link="{joint.parent}"/><child link="{joint.child}"/>',
            f'<origin xyz="0 0 {z}" rpy="0 0 0"/><axis xyz="{ax}"/>',
            f'<limit lower="{joint.lower}" upper="{joint.upper}" effort="{joint.effort}"'
            f' velocity="{joint.velocity}"/>',
            "</joint>",
        ]
    lines.append("</robot>")
    return "\n".join(lines)


def design_urdf(design: Design, robot_name: str = "robot") -> str:
    try:
        from adclient.urdf import design_to_urdf
    except ImportError:
        return _fallback_urdf(design, robot_name)
    return design_to_urdf(design, robot_name=robot_name)


def write_urdf(design: Design, path: Path) -> Path:
    path.write_text(design_urdf(design))
    return path


EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
HALF_PI = 1.5707963267948966


def example_study(name: str):
    """The StudyCreate of examples/<name>.yaml."""
    import yaml

    from adclient.schemas import StudyCreate

    return StudyCreate.model_validate(yaml.safe_load((EXAMPLES / f"{name}.yaml").read_text()))


def stand_up_study(client: Client, *, max_trials: int, **task: object) -> StudyHandle:
    """The example stand-up study, as its file sets it, with a budget, task changes and
    the random proposer: the tests that use it are about workers and leases, not
    proposals, and qei would fit a model in the server for every ask past its first two."""
    body = example_study("stand-up").model_dump(mode="json", exclude_unset=True)
    body["max_trials"] = max_trials
    body["proposer"] = {"name": "random", "seed": 0}
    body["task"].update(task)
    return client.create_study(body)


def ppo_trained_trial(
    client: Client, server: ServerProcess, workdir: Path, *, train_steps: int
) -> Trial:
    """The one trial of a stand-up study that a real ``adworker`` trained with PPO for
    ``train_steps`` (a training episode every 32) and evaluated, complete."""
    return trained_trial(client, server, workdir, learner="ppo", train_steps=train_steps)


def fast_trained_trial(client: Client, server: ServerProcess, workdir: Path) -> Trial:
    """The one trial of a stand-up study that a real ``adworker`` trained with the fast
    learner (the cheapest that runs evaluation episodes) and evaluated, complete."""
    return trained_trial(client, server, workdir, learner="fast")


def trained_trial(client: Client, server: ServerProcess, workdir: Path, **task: object) -> Trial:
    """The one trial of a stand-up study (its task updated with ``task``) that a real
    ``adworker`` trained and evaluated, complete."""
    body = example_study("stand-up").model_dump(mode="json")
    body["max_trials"] = 1
    body["task"].update(task)
    study = client.create_study(body)
    worker = WorkerProcess(server, workdir, str(task["learner"]), "--no-render", "--max-jobs", "1")
    try:
        assert worker.wait() == 0, worker.log()
    finally:
        worker.stop()
    [trial] = client.trials(study.id)
    assert trial.state == "complete", worker.log()
    return trial


def running_trial(client: Client, study_id: int, worker_id: str) -> Trial | None:
    """The study's running trial that ``worker_id`` holds, if any."""
    for trial in client.trials(study_id, state="running"):
        if trial.worker_id == worker_id:
            return trial
    return None


def make_job(example: str, specs: dict[str, float], trial_id: int = 1, **task: object):
    """A Job for a single-structure example, its vector encoding ``specs``."""
    from datetime import UTC, datetime, timedelta

    from adclient.decode import identity_representation
    from adclient.encode import encode
    from adclient.schemas import Job

    study = example_study(example)
    representation = identity_representation(study.space)
    vector = encode(study.space, representation, specs)
    task_config = study.task.model_copy(update=task)
    return Job(
        trial_id=trial_id,
        study_id=1,
        number=trial_id - 1,
        attempt=1,
        vector=vector,
        params=dict(specs),
        task=task_config,
        space=study.space,
        representation=representation,
        lease_expires_at=datetime.now(UTC) + timedelta(minutes=5),
    )


def stand_up_specs(theta: float, phi: float, length: float = 0.4) -> dict[str, float]:
    """Stand-up specs with both joints at (theta, phi) and equal link lengths."""
    return {
        "a.length": length,
        "b.length": length,
        "c.length": length,
        "b.joint.axis_theta": theta,
        "b.joint.axis_phi": phi,
        "c.joint.axis_theta": theta,
        "c.joint.axis_phi": phi,
    }


CHAIN, STAR = 0, 1
"""The trees of :func:`two_tree_body`: a chain of three links (two joints), a star of
four (three joints), so their controllers' observation and action spaces differ."""


def two_tree_body(task: dict[str, Any], name: str, max_trials: int = 20) -> dict[str, Any]:
    """examples/multi-structure.yaml cut to two trees (``CHAIN``, ``STAR``), proposed at
    random, with ``task``."""
    body = yaml.safe_load((EXAMPLES / "multi-structure.yaml").read_text())
    body["space"]["structures"] = [[["a", "b"], ["b", "c"]], [["a", "b"], ["a", "c"], ["a", "d"]]]
    body["space"]["instances"] = body["space"]["instances"][:4]
    body["proposer"] = {"name": "random", "seed": 3}
    body["task"] = task
    return {**body, "name": name, "max_trials": max_trials}


def nearest_transfer_body(learner: str, train_steps: int, transfer_steps: int) -> dict[str, Any]:
    """A :func:`two_tree_body` study of lift-highest with ``transfer: nearest``."""
    task = {
        "name": "lift-highest",
        "learner": learner,
        "train_steps": train_steps,
        "eval_episodes": 1,
        "transfer": "nearest",
        "transfer_steps": transfer_steps,
    }
    return two_tree_body(task, f"transfer-{learner}")


def tree_design(tree: int, angle: float) -> dict[str, Any]:
    """Params of a design of ``tree`` (:func:`two_tree_body`) with every joint axis at
    (angle, angle)."""
    children = ["b", "c"] if tree == CHAIN else ["b", "c", "d"]
    params: dict[str, Any] = {"structure_index": tree}
    for child in children:
        params[f"{child}.joint.axis_theta"] = angle
        params[f"{child}.joint.axis_phi"] = angle
    return params


def arm(length: float) -> dict[str, Any]:
    """Params of diagonal-gesture's arm (a chain of three links) with links of
    ``length``: the plugin's arm-length task scores it 3 * length, whatever its
    controller does."""
    params: dict[str, Any] = {f"{link}.length": length for link in "abc"}
    for child in "bc":
        params[f"{child}.joint.axis_theta"] = 1.0
        params[f"{child}.joint.axis_phi"] = 1.0
    return params


def run_designs(
    server: ServerProcess, tmp_path: Path, client: Client, study_id: int, *designs: dict
) -> list[Trial]:
    """Enqueue designs and let one worker evaluate them, one after the other; each must
    complete."""
    added = client.add_trials(study_id, [{"params": params} for params in designs])
    worker = WorkerProcess(
        server, tmp_path, f"w{added[0].id}", "--no-render", "--max-jobs", str(len(added))
    )
    try:
        assert worker.wait() == 0, worker.log()
    finally:
        worker.stop()
    trials = [client.get_trial(trial.id) for trial in added]
    assert all(trial.state == "complete" for trial in trials), worker.log()
    return trials


def stand_up(learner: str, train_steps: int, pruner: dict[str, Any]) -> dict[str, Any]:
    """The example stand-up study (two trials, proposed at random) of ``learner`` under
    ``pruner``, one evaluation episode a trial."""
    body = yaml.safe_load((EXAMPLES / "stand-up.yaml").read_text())
    body["proposer"] = {"name": "random", "seed": 4}
    body["task"] = {
        "name": "stand-up",
        "learner": learner,
        "train_steps": train_steps,
        "eval_episodes": 1,
    }
    return {**body, "name": f"pruned-{learner}", "max_trials": 2, "pruner": pruner}


RUNG = 256
"""The one ASHA rung of :func:`promoting` (steps)."""


def promoting(learner: str, train_steps: int) -> dict[str, Any]:
    """Four stand-up designs under ASHA with promotion, one rung (256 steps): the first
    three pause there (a rung needs more than bootstrap_count = 3 values to promote), the
    fourth brings the top half (two of four) on, so at least one paused trial is
    promoted and resumed whatever the scores."""
    options = {
        "min_resource": RUNG,
        "reduction_factor": 2,
        "bootstrap_count": 3,
        "max_resource": 2 * RUNG,
        "promotion": True,
    }
    pruner = {"name": "asha", "options": options, "report_every": 128}
    return {**stand_up(learner, train_steps, pruner), "max_trials": 4}
