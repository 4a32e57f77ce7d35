"""Issue 39, one fixed design: a space that searches nothing (a design space with every
spec given and one structure, a template without params) is a study of that design, not
a 422. No proposer runs: every ask and lease is the design, each trial on its own seed;
``max_trials`` counts the repeats (5 unset); enqueue and add take only that design; the
spread of the values is at ``/spread``. On a real ``adserver`` over SQLite alone (nothing
here is the database's: the trials are stored as a random proposer's are, and the
spread is one plain read of the values)."""

from __future__ import annotations

import statistics
from pathlib import Path
from typing import Any

import httpx
import pytest
import yaml

from adclient import Client
from adclient.testing.servers import ServerProcess

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.parametrize("shared_server", ["sqlite"], indirect=True),  # see above
]

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
ARM = (EXAMPLES / "templates" / "arm.urdf.xacro").read_text()
"""A xacro whose args and properties have defaults: without params, one robot."""


def one_design(name: str, **fields: Any) -> dict[str, Any]:
    """examples/one-design.yaml as an ask/tell study (no task, no max_trials)."""
    body = yaml.safe_load((EXAMPLES / "one-design.yaml").read_text())
    del body["task"], body["max_trials"]
    return body | {"name": name} | fields


def created(http: httpx.Client, body: dict[str, Any]) -> dict[str, Any]:
    answer = http.post("/api/v1/studies", json=body)
    assert answer.status_code == 201, answer.text
    study: dict[str, Any] = answer.json()
    return study


def refused(http: httpx.Client, path: str, body: Any) -> str:
    """The detail of a 422 answer to ``body``."""
    answer = http.post(path, json=body)
    assert answer.status_code == 422, answer.text
    return str(answer.json()["detail"])


def test_a_design_space_that_searches_nothing_proposes_its_design_on_distinct_seeds(
    shared_server: ServerProcess,
) -> None:
    with httpx.Client(base_url=shared_server.url, timeout=60) as http:
        study = created(http, one_design("hand-made", proposer={"name": "qei", "seed": 7}))
        assert study["fixed"] is True and study["max_trials"] == 5
        asked = http.post(f"/api/v1/studies/{study['id']}/ask", json={"count": 3}).json()
        trials = asked["trials"]
        assert [t["info"] for t in trials] == [{"method": "fixed", "seed": s} for s in (7, 8, 9)]
        assert all(t["vector"] == [] and t["params"] == trials[0]["params"] for t in trials)
        params = trials[0]["params"]
        assert params["a.length"] == params["c.length"] == 0.4
        assert params["b.joint.axis_phi"] == 1.5707963267948966
        more = http.post(f"/api/v1/studies/{study['id']}/ask", json={"count": 2}).json()
        assert [t["info"]["seed"] for t in more["trials"]] == [10, 11]
        over = http.post(f"/api/v1/studies/{study['id']}/ask", json={"count": 1})
        assert over.status_code == 409 and "max_trials=5" in over.text
        values = [0.5, 0.25, 1.0, 0.75]
        for trial, value in zip(trials + more["trials"], values, strict=False):
            told = http.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": value})
            assert told.status_code == 200, told.text
        spread = http.get(f"/api/v1/studies/{study['id']}/spread").json()
        assert spread == {
            "study_id": study["id"],
            "fixed": True,
            "objectives": [
                {
                    "name": "value",
                    "n": 4,
                    "mean": 0.625,
                    "std": statistics.stdev(values),
                    "min": 0.25,
                    "median": 0.625,
                    "max": 1.0,
                }
            ],
        }
        # Several structures with every spec given are searched (over the structures).
        searched = one_design("two trees", max_trials=4)
        searched["space"]["structures"] = [[["a", "b"], ["b", "c"]], [["a", "b"], ["a", "c"]]]
        assert created(http, searched)["fixed"] is False


def test_a_template_without_params_is_leased_as_its_robot_with_each_trial_s_seed(
    shared_server: ServerProcess,
) -> None:
    body = {
        "name": "my-arm",
        "space": {"type": "template", "template": ARM},
        "task": {"name": "lift-highest", "learner": "fast", "seed": 100},
    }
    with Client(shared_server.url) as client:
        study = client.create_study(body)
        info = study.cached_info
        assert info.fixed and info.max_trials == 5 and info.space.params == []
        jobs = [client.lease("raw-worker", tasks=["lift-highest"]) for _ in range(2)]
        seeds = []
        for job in jobs:
            assert job is not None and job.study_id == study.id
            assert job.vector == [] and job.params == {}
            assert job.urdf is not None and '<link name="hand">' in job.urdf
            seeds.append(job.task.seed)
        assert seeds == [100 + job.number for job in jobs] == [100, 101]
        assert [t.info for t in study.trials] == [{"method": "fixed", "seed": s} for s in seeds]
        listed = next(s for s in client.studies() if s.id == study.id)
        assert listed.fixed and listed.proposer.name == "qei"  # kept, never run


def test_enqueue_and_add_take_only_the_one_design(shared_server: ServerProcess) -> None:
    url = shared_server.url
    with Client(url) as client, httpx.Client(base_url=url, timeout=60) as http:
        study = client.create_study(one_design("enqueued", max_trials=8))
        path = f"/api/v1/studies/{study.id}/trials"
        first = study.enqueue_trial({})
        params = first.params
        assert first.vector == [] and params["b.length"] == 0.4
        assert study.enqueue_trial(params).params == params  # its own params, as shown
        added = study.add_trial(params | {"a.length": 0.4 + 1e-12}, value=2.0)
        assert added.state == "complete" and added.info == {"source": "added"}
        assert study.enqueue_trial({}, skip_if_exists=True).id == first.id  # as it says
        detail = refused(http, path, {"params": {"a.length": 0.5}})
        assert "a.length = 0.5 is not the study's one design, whose a.length is 0.4" in detail
        detail = refused(http, path, {"params": {"b.joint.axis": [0, 0, 1]}})
        assert "b.joint.axis = [0, 0, 1] is not the study's one design" in detail
        assert "'x' is no param of the study's one design" in refused(
            http, path, {"params": {"x": 1.0}}
        )
        assert study.info.n_trials == 3  # the refused ones stored nothing
        template = client.create_study(
            {"name": "arm-once", "space": {"type": "template", "template": ARM}}
        )
        detail = refused(http, f"/api/v1/studies/{template.id}/trials", {"params": {"n": 2}})
        assert "'n' is no param of the study's one design (it has no params)" in detail
        assert template.enqueue_trial({}).params == {}
        assert client.spread(study.id).objectives[0].n == 1  # the added evaluation


def test_what_would_tie_one_repeat_to_another_is_refused(shared_server: ServerProcess) -> None:
    with httpx.Client(base_url=shared_server.url, timeout=60) as http:
        pruned = one_design("pruned", pruner={"name": "median"})
        assert "pruner: 'median' stops trials by the others' values" in refused(
            http, "/api/v1/studies", pruned
        )
        body = yaml.safe_load((EXAMPLES / "one-design.yaml").read_text())
        body["task"].update(learner="ppo", transfer="nearest")  # a learner that can
        assert "task.transfer: 'nearest' starts a trial from another's controller" in refused(
            http, "/api/v1/studies", body
        )
        names = {study["name"] for study in http.get("/api/v1/studies").json()}
        assert not names & {"pruned", body["name"]}  # nothing stored


def test_a_spread_past_the_float_range_is_null_not_a_500(shared_server: ServerProcess) -> None:
    """Repeats told 1e308 each are finite, but their sum is not: the spread answers
    their mean and median (1e308) and, for +-1.7e308, a std past the float range as null,
    where ``statistics`` raised OverflowError and the route answered 500."""
    with httpx.Client(base_url=shared_server.url, timeout=30) as http:
        for name, values, expected in [
            ("huge", [1e308, 1e308], {"mean": 1e308, "std": 0.0, "median": 1e308}),
            ("wide", [1.7e308, -1.7e308], {"mean": 0.0, "std": None, "median": 0.0}),
        ]:
            study = created(http, one_design(name, max_trials=2))
            trials = http.post(f"/api/v1/studies/{study['id']}/ask", json={"count": 2})
            for trial, value in zip(trials.json()["trials"], values, strict=True):
                told = http.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": value})
                assert told.status_code == 200, told.text
            answer = http.get(f"/api/v1/studies/{study['id']}/spread")
            assert answer.status_code == 200, answer.text
            (objective,) = answer.json()["objectives"]
            assert {k: objective[k] for k in expected} == expected, objective
            assert (objective["min"], objective["max"]) == (min(values), max(values))
