"""Templates end to end (issue 28): ``adclient submit --wait`` of the template-arm
example against a real adserver with a real adworker. Each trial's robot is the user's
xacro expanded at its params: the worker simulates it (its mass metric is the expanded
URDF's), ``/trials/{id}/urdf`` and the worker's robot.urdf artifact are that URDF, and a
template that does not expand, reads a file, lacks a task's link or would run a command
(issue 36) is a 422 naming it that stores nothing."""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree
from html import escape
from pathlib import Path

import httpx
import pytest
import yaml

from adclient import Client
from adclient.testing.workers import run_adclient
from adclient.urdf_model import read_urdf

pytestmark = [pytest.mark.slow, pytest.mark.e2e]

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
TRIALS = 3
RUN_COMMAND = (  # issue 36: Python's eval of the robot's name ran the command
    "(lambda: [c for c in ().__class__.__base__.__subclasses__() if c.__name__ == "
    "'_wrap_close'][0].__init__.__globals__['system']('touch pwned'))()"
)


def small_copy(tmp_path: Path) -> Path:
    """The example with a small budget, its template path still relative to it."""
    body = yaml.safe_load((EXAMPLES / "template-arm.yaml").read_text(encoding="utf-8"))
    assert body["space"]["template"] == "templates/arm.urdf.xacro"
    body["max_trials"] = TRIALS
    body["task"].update(train_steps=64, eval_episodes=1)
    (tmp_path / "templates").mkdir()
    (tmp_path / "templates" / "arm.urdf.xacro").write_bytes(
        (EXAMPLES / "templates" / "arm.urdf.xacro").read_bytes()
    )
    path = tmp_path / "template-arm.yaml"
    path.write_text(yaml.safe_dump(body), encoding="utf-8")
    return path


def test_the_template_arm_runs_from_its_study_file(server, workers, tmp_path):
    workers(server, "template")
    done = run_adclient(server, "submit", "--wait", "--poll", "0.2", str(small_copy(tmp_path)))
    assert done.returncode == 0, done.stderr
    (study,) = httpx.get(f"{server.url}/api/v1/studies").json()
    with Client(server.url) as client:
        trials = client.get_study(study["id"]).trials
        assert [trial.state for trial in trials] == ["complete"] * TRIALS
        for trial in trials:
            urdf = httpx.get(f"{server.url}/api/v1/trials/{trial.id}/urdf").text
            lengths = {
                link.get("name"): float(cylinder.get("length", "nan"))
                for link in ElementTree.fromstring(urdf).iter("link")
                for cylinder in link.iter("cylinder")
            }
            assert lengths == {
                "upper_arm": trial.params["upper_length"],
                "forearm": trial.params["fore_length"],
            }
            assert trial.metrics["mass"] == pytest.approx(read_urdf(urdf).mass, rel=1e-12)
            built = httpx.get(f"{server.url}/api/v1/trials/{trial.id}/artifacts/robot.urdf")
            assert built.status_code == 200 and built.text == urdf
        # the robots differ as their params do: three designs, three masses
        assert len({trial.metrics["mass"] for trial in trials}) == TRIALS


def test_a_bad_template_is_a_422_that_stores_nothing(server, tmp_path):
    template = (EXAMPLES / "templates" / "arm.urdf.xacro").read_text()
    body = yaml.safe_load((EXAMPLES / "template-arm.yaml").read_text(encoding="utf-8"))
    cases = [
        (
            template.replace('length="${fore}"', 'length="${forarm}"'),
            {},
            "NameError: name 'forarm'",
        ),
        (template.replace('type="fixed"', 'type="floating"'), {}, "joint 'wrist' (line"),
        (
            template.replace(
                '<link name="foot">', '<xacro:include filename="/etc/passwd"/><link name="foot">'
            ),
            {},
            "xacro:include",
        ),
        (template, {"name": "stand-up", "learner": "fast"}, "task.options.lifted_link"),
        (
            template.replace('<robot name="arm"', f'<robot name="${{{escape(RUN_COMMAND)}}}"'),
            {},
            "line 6: lambda `lambda: [c for c in ().__class__",
        ),
    ]
    with httpx.Client(base_url=server.url, timeout=60) as http:
        for text, task, named in cases:
            sent = {**body, "space": {**body["space"], "template": text}}
            if task:
                sent["task"] = task
            refused = http.post("/api/v1/studies", json=sent)
            assert refused.status_code == 422, refused.text
            assert named in refused.json()["detail"]
        assert http.get("/api/v1/studies").json() == []
    assert not (server.workdir / "pwned").exists()  # where the expanding child runs
    # the CLI reads the file and names one it cannot read
    missing = tmp_path / "study.yaml"
    missing.write_text(
        yaml.safe_dump({**body, "space": {**body["space"], "template": "nope.xacro"}})
    )
    failed = run_adclient(server, "submit", str(missing))
    assert failed.returncode == 1
    assert "space.template: cannot read" in failed.stderr and "nope.xacro" in failed.stderr
