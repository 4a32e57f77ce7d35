"""The replay contract end to end: a real adworker records its last evaluation episode as
``replay.json`` (adclient.schemas.Replay), and what it recorded is what the task scored."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from adclient import Client
from adclient.schemas import REPLAY_ARTIFACT, Replay
from adclient.schemas.replays import MAX_FRAMES
from adclient.spawn import link_frames
from adclient.testing.servers import ServerProcess
from adclient.testing.workers import run_adclient
from adclient.urdf_model import read_urdf
from adworker.evaluate import evaluate_job
from adworker.replay import ReplayRecorder, quaternion_products, root_frames, rotation_matrices
from tests.workers.robots import HALF_PI, fast_trained_trial, make_job, stand_up_specs


@pytest.mark.e2e
def test_a_real_workers_replay_reads_back_and_ends_where_the_task_scored(
    server: ServerProcess, tmp_path: Path
) -> None:
    with Client(server.url) as client:
        trial = fast_trained_trial(client, server, tmp_path)
        written = client.get_artifact(trial, REPLAY_ARTIFACT)
        replay = client.trial_replay(trial)
        curve = client.trial_curve(trial)
        model = read_urdf(client.trial_urdf(trial))

    assert replay.to_json() == written
    assert replay.trial_id == trial.id
    last = curve.evaluation[-1]  # the episode recorded: the last, robot.png's
    assert replay.seed == last.seed
    assert len(replay.frames) == len(last.metric) + 1  # the reset, then each control step
    assert replay.every == 1
    assert replay.joints == ["a_b", "b_c"]
    assert replay.control_period == pytest.approx(0.1)
    frames = np.array(replay.frames)
    assert np.ptp(frames[:, 7:], axis=0).min() > 0.5  # both joints fold the arch up
    assert np.ptp(frames[:, 2]) > 0.01  # and the root moves
    assert np.allclose(np.linalg.norm(frames[:, 3:7], axis=1), 1.0, atol=1e-3)

    # The task's metric at the last step, stand-up's height of b's centre, recomputed from
    # the last frame posed on the URDF: the replay is the simulator's pose.
    assert last.metric[-1] > 0.1
    k = len(replay.frames) - 1
    assert b_centre_height(model, replay, k) == pytest.approx(last.metric[-1], abs=2e-3)

    # adclient writes it as an animated GIF, one picture per recorded step, that moves.
    gif = tmp_path / "stand.gif"
    written_gif = run_adclient(server, "replay", str(trial.id), "--out", str(gif))
    assert written_gif.returncode == 0, written_gif.stderr
    assert f"wrote {gif}" in written_gif.stdout
    with Image.open(gif) as image:
        assert image.format == "GIF" and image.is_animated
        assert image.n_frames == len(replay.frames)
        assert image.info["duration"] == 100  # real time: a control period each
        first = np.asarray(image.convert("RGB"))
        image.seek(image.n_frames - 1)
        final = np.asarray(image.convert("RGB"))
    assert (first != final).any(axis=2).mean() > 0.01  # the arch has risen
    again = run_adclient(server, "replay", str(trial.id), "--out", str(gif))
    assert again.returncode == 1 and "--force" in again.stderr


def b_centre_height(model, replay: Replay, k: int) -> float:
    """stand-up's metric at frame ``k``, recomputed from the replay posed on the URDF: the
    height of link b's shape centre."""
    turn = rotation_matrices(np.array(replay.orientation(k)))
    at = np.array(replay.position(k))
    for name, rotation, origin in link_frames(model, turn, at, replay.joint_positions(k)):
        if name == "b":
            [shape] = model.links["b"].shapes
            return float((origin + rotation @ np.array(shape.origin.xyz))[2])
    raise AssertionError("no link b")


@pytest.mark.parametrize("simulator", ["pybullet", "mujoco"])
def test_each_engines_replay_ends_in_the_pose_it_scored(simulator: str, tmp_path: Path) -> None:
    """Each engine reports the root at its own pose frame (PyBullet's inertial frame,
    MuJoCo's body axes at the centre of mass): the replay holds the URDF's root frame on
    both, so its frames posed on the URDF give the task's per-step metric."""
    job = make_job("stand-up", stand_up_specs(HALF_PI, HALF_PI), simulator=simulator)
    evaluation = evaluate_job(job, tmp_path, render=False)
    artifacts = {artifact.name: artifact.data for artifact in evaluation.artifacts}
    replay = Replay.model_validate_json(artifacts[REPLAY_ARTIFACT])
    model = read_urdf(artifacts["robot.urdf"].decode())
    last = evaluation.episodes[-1]
    assert replay.seed == last.seed and len(replay.frames) == len(last.metric) + 1
    standing = [k for k, value in enumerate(last.metric, start=1) if value > 0]
    assert len(standing) > 10
    for k in standing:
        assert b_centre_height(model, replay, k) == pytest.approx(last.metric[k - 1], abs=2e-3)


def test_root_frames_undo_the_engines_constant_offset() -> None:
    """A pose frame that is the root frame moved by an offset gives back the root frame."""
    rng = np.random.default_rng(0)
    turns = rng.normal(size=(5, 4))
    turns /= np.linalg.norm(turns, axis=1, keepdims=True)
    ats = rng.normal(size=(5, 3))
    offset_turn = np.array([0.0, np.sin(0.3), 0.0, np.cos(0.3)])
    offset_at = np.array([0.1, -0.2, 0.05])
    poses = quaternion_products(turns, offset_turn)
    positions = ats + np.einsum("nij,j->ni", rotation_matrices(turns), offset_at)
    got_at, got_turn = root_frames(positions, poses, (tuple(ats[0]), tuple(turns[0])))
    assert np.allclose(got_at, ats)
    same = np.where(turns[:, 3:4] < 0, -turns, turns)
    assert np.allclose(got_turn, same)


class _Env:
    """Just what the recorder reads of an env: long episodes of a one-joint robot."""

    class robot:
        spawn = type("Spawn", (), {"position": (0.0, 0.0, 0.0), "orientation": (0, 0, 0, 1)})
        joints = [type("Joint", (), {"name": "j"})]

    class sim:
        control_period = 0.02

    def __init__(self) -> None:
        self.t = 0

    def snapshot(self):
        pose = ((float(self.t), 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
        return type("Snapshot", (), {"poses": [pose], "q": [self.t * 0.001]})

    def reset(self, seed=None):
        self.t = 0

    def step(self, action):
        self.t += 1


def test_a_long_episode_is_bounded_and_keeps_its_last_pose() -> None:
    recorder = ReplayRecorder(_Env())
    recorder.reset(seed=3)
    for _ in range(5_000):
        recorder.step(None)
    replay = recorder.replay()
    assert replay is not None
    assert len(replay.frames) <= MAX_FRAMES
    assert replay.every == 5
    assert replay.frame_period == pytest.approx(0.1)
    assert replay.frames[-1][0] == 5_000.0  # the last step's pose, the one scored
    assert Replay.model_validate_json(replay.to_json()) == replay
