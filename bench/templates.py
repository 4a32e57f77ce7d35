"""What a template costs (issue 28): expanding a user's xacro in a child process of its
own (limited in memory, CPU and environment: ``adclient.templates``), against the job
it is for and against writing a design's URDF.

Measured side by side in one run, on examples/templates/arm.urdf.xacro:

- ``expand, isolated``: ``expand_isolated`` at one point (what a worker does per job
  and the server per ``/trials/{id}/urdf``): a Python start, xacro, the expansion;
- ``expand, in process``: ``expand`` (what isolation adds is the difference);
- ``check at creation``: ``check_template`` (three points expanded in one child, each
  read as a robot), what creating a template study adds;
- ``design URDF``: ``design_to_urdf`` of the stand-up example's design, for scale;
- ``template job``: ``evaluate_job`` of the template-arm example with its own learner
  (``fast``) and budget, the expansion included.

Goal: the isolated expansion at most 5% of the cheapest job it is for (the fast
learner's; an RL job is 10 to 100 times longer).

Run: ``.venv/bin/python bench/templates.py`` (under a minute); writes
bench/results/templates.json.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from pathlib import Path

import yaml

from adclient.boxspace import BoxEncoding
from adclient.decode import decode, identity_representation, spec_layout
from adclient.schemas import Job, StudyCreate, TemplateSpace
from adclient.templates import check_template, expand, expand_isolated
from adclient.urdf import design_to_urdf

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
POINT = {"upper_length": 0.3, "fore_length": 0.25, "hand_radius": 0.05}


def median_seconds(run: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        run()
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def template_study() -> StudyCreate:
    body = yaml.safe_load((EXAMPLES / "template-arm.yaml").read_text())
    body["space"]["template"] = (EXAMPLES / "templates" / "arm.urdf.xacro").read_text()
    return StudyCreate.model_validate(body)


def template_job_seconds(study: StudyCreate, repeats: int) -> float:
    from adworker.evaluate import evaluate_job

    assert isinstance(study.space, TemplateSpace) and study.task is not None
    job = Job(
        trial_id=1,
        study_id=1,
        number=0,
        attempt=1,
        vector=BoxEncoding.of(study.space.model_dump(mode="json")).encode(POINT).tolist(),
        params=POINT,
        task=study.task,
        space=study.space,
        representation=None,
        lease_expires_at=datetime.now(UTC) + timedelta(minutes=5),
    )
    with tempfile.TemporaryDirectory() as folder:
        return median_seconds(lambda: evaluate_job(job, Path(folder), render=False), repeats)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--jobs", type=int, default=3)
    args = parser.parse_args()
    study = template_study()
    assert isinstance(study.space, TemplateSpace)
    template, params = study.space.template, study.space.params
    stand_up = StudyCreate.model_validate(yaml.safe_load((EXAMPLES / "stand-up.yaml").read_text()))
    assert not isinstance(stand_up.space, TemplateSpace)
    design = decode(
        stand_up.space,
        identity_representation(stand_up.space),
        [0.5] * spec_layout(stand_up.space).size,  # type: ignore[arg-type]
    )
    rows = {
        "expand, isolated": median_seconds(
            lambda: expand_isolated(template, [POINT]), args.repeats
        ),
        "expand, in process": median_seconds(lambda: expand(template, POINT), args.repeats),
        "check at creation": median_seconds(lambda: check_template(template, params), args.repeats),
        "design URDF": median_seconds(lambda: design_to_urdf(design), args.repeats),
        "template job (fast learner)": template_job_seconds(study, args.jobs),
    }
    job = rows["template job (fast learner)"]
    share = rows["expand, isolated"] / job
    print(f"{'what':32} {'median ms':>10} {'of a job':>9}")
    for what, seconds in rows.items():
        print(f"{what:32} {1000 * seconds:10.2f} {seconds / job:9.2%}")
    print(
        f"goal: isolated expansion <= 5% of a fast-learner job: {share:.2%}, "
        f"{'met' if share <= 0.05 else 'missed'}"
    )
    out = ROOT / "bench" / "results" / "templates.json"
    out.write_text(json.dumps({"seconds": rows, "share_of_job": share}, indent=2) + "\n")


if __name__ == "__main__":
    main()
