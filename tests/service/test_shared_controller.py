"""Issue 38, the service's side of ``task.transfer: shared``: each study's shared
controller as a real ``adserver`` keeps it (a version per update, advanced by
compare-and-set), what a leased job carries, and the worker's side of merging
(:mod:`adworker.sharing`) against that server. Workers of our own (SDK lease, artifact
upload, tell) stand in for adworker here; tests/workers/test_shared_worker_e2e.py runs
adworker itself."""

from __future__ import annotations

import logging
import threading
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import yaml

from adclient import Client
from adclient.errors import Conflict, Invalid
from adclient.schemas import SHARED_ARTIFACT, Job, SharedVersion
from adclient.testing.servers import ServerProcess
from adworker import shared_weights
from adworker.runner import SHARED_FILE
from adworker.sharing import advance_shared
from adworker.sources import fetch_shared

pytestmark = [pytest.mark.e2e, pytest.mark.xdist_group("transfer")]

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def study_body(name: str, task: str, **extra: Any) -> dict[str, Any]:
    """examples/multi-structure.yaml (six trees) as a study of workers of our own with a
    shared controller; ``task`` names its jobs apart from other tests' on the server."""
    body = yaml.safe_load((EXAMPLES / "multi-structure.yaml").read_text())
    body["proposer"] = {"name": "random", "seed": 3}
    body["task"] = {"name": task, "external": True, "transfer": "shared"}
    return {**body, "name": name, "max_trials": 20, **extra}


def weights(seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {"encoder.weight": rng.normal(size=(4, 3)), "log_std": rng.normal(size=1)}


def upload(client: Client, job: Job, data: bytes, worker: str = "w") -> None:
    client.put_artifact(job.trial_id, SHARED_ARTIFACT, data, worker_id=worker)


def test_versions_advance_by_compare_and_set_and_jobs_carry_the_current_one(
    shared_server: ServerProcess,
) -> None:
    """The first update makes version 1 (a job leased before it carries none); a job
    leased after carries the current version; an update made from an older version is
    a 409 naming the current one and lands once offered on it; a repeat once taken
    answers the same version; each trial keeps what it started from and made."""
    task = "shared-versions"
    with Client(shared_server.url) as client:
        study = client.create_study(study_body("shared versions", task))
        assert client.shared_controller(study.id) is None
        first = client.lease("w", tasks=[task])
        assert first is not None and first.shared is None
        upload(client, first, shared_weights.encode(weights(1)))
        made = client.advance_shared(first.trial_id, worker_id="w", base_version=None)
        assert (made.version, made.trial_id) == (1, first.trial_id)
        again = client.advance_shared(first.trial_id, worker_id="w", base_version=None)
        assert (again.version, again.trial_id) == (1, first.trial_id)
        client.tell(first.trial_id, 0.5, worker_id="w")

        second, third = client.lease("w2", tasks=[task]), client.lease("w3", tasks=[task])
        assert second is not None and third is not None
        assert second.shared is not None and third.shared is not None
        assert (second.shared.version, second.shared.trial_id) == (1, first.trial_id)
        upload(client, second, shared_weights.encode(weights(2)), "w2")
        upload(client, third, shared_weights.encode(weights(3)), "w3")
        assert client.advance_shared(second.trial_id, worker_id="w2", base_version=1).version == 2
        with pytest.raises(Conflict, match="at version 2, not 1"):
            client.advance_shared(third.trial_id, worker_id="w3", base_version=1)
        assert client.advance_shared(third.trial_id, worker_id="w3", base_version=2).version == 3
        current = client.shared_controller(study.id)
        assert current is not None and (current.version, current.trial_id) == (3, third.trial_id)
        for job, worker in ((second, "w2"), (third, "w3")):
            client.tell(job.trial_id, 0.1, worker_id=worker)
        fourth = client.lease("w", tasks=[task])
        assert fourth is not None and fourth.shared is not None
        assert (fourth.shared.version, fourth.shared.trial_id) == (3, third.trial_id)
        info = {trial.id: trial.info.get("shared") for trial in client.trials(study.id)}
        assert info[first.trial_id] == {"from": None, "version": 1}
        assert info[second.trial_id] == {"from": 1, "version": 2}
        assert info[third.trial_id] == {"from": 2, "version": 3}
        client.tell(fourth.trial_id, state="failed", message="done", worker_id="w")


def test_what_cannot_advance_a_shared_controller_is_refused_and_changes_nothing(
    shared_server: ServerProcess,
) -> None:
    """No update uploaded, another worker naming the trial, a finished trial, a study
    without ``task.transfer: shared``, and bodies the schema refuses: each a 4xx naming
    what is wrong, and the study's version as before."""
    task = "shared-refusals"
    with Client(shared_server.url) as client:
        study = client.create_study(study_body("shared refusals", task))
        job = client.lease("w", tasks=[task])
        assert job is not None
        with pytest.raises(Conflict, match=r"no shared-controller\.npz uploaded"):
            client.advance_shared(job.trial_id, worker_id="w", base_version=None)
        upload(client, job, shared_weights.encode(weights(1)))
        with pytest.raises(Conflict, match="does not hold the lease"):
            client.advance_shared(job.trial_id, worker_id="intruder", base_version=None)
        with pytest.raises(Invalid, match="base_version"):
            client.advance_shared(job.trial_id, worker_id="w", base_version=0)
        response = httpx.post(
            f"{shared_server.url}/api/v1/trials/{job.trial_id}/shared-controller",
            json={"worker_id": "w", "base_version": None, "weights": "x"},
        )
        assert response.status_code == 422 and "weights" in response.text
        assert client.shared_controller(study.id) is None
        client.tell(job.trial_id, 0.2, worker_id="w")
        with pytest.raises(Conflict, match="does not hold the lease"):
            client.advance_shared(job.trial_id, worker_id="w", base_version=None)
        assert client.shared_controller(study.id) is None

        plain = client.create_study(
            {
                **study_body("no sharing", "shared-none"),
                "task": {"name": "shared-none", "external": True},
            }
        )
        other = client.lease("w", tasks=["shared-none"])
        assert other is not None and other.study_id == plain.id and other.shared is None
        upload(client, other, shared_weights.encode(weights(1)))
        with pytest.raises(Invalid, match=r"no task\.transfer: shared"):
            client.advance_shared(other.trial_id, worker_id="w", base_version=None)
        assert client.shared_controller(plain.id) is None
        client.tell(other.trial_id, 0.2, worker_id="w")


def test_a_study_never_sees_another_studys_shared_controller(
    shared_server: ServerProcess, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Two studies sharing: the second's jobs carry none of the first's versions, and a
    job naming a trial of another study as its version (a forged or mistaken job) is
    not downloaded: the worker starts from the study's initial weights."""
    with Client(shared_server.url) as client:
        one = client.create_study(study_body("sharing one", "shared-one"))
        two = client.create_study(study_body("sharing two", "shared-two"))
        job = client.lease("w", tasks=["shared-one"])
        assert job is not None
        upload(client, job, shared_weights.encode(weights(1)))
        client.advance_shared(job.trial_id, worker_id="w", base_version=None)
        client.tell(job.trial_id, 0.3, worker_id="w")
        assert client.shared_controller(one.id) is not None
        assert client.shared_controller(two.id) is None
        theirs = client.lease("w", tasks=["shared-two"])
        assert theirs is not None and theirs.study_id == two.id and theirs.shared is None
        forged = theirs.model_copy(update={"shared": client.shared_controller(one.id)})
        with caplog.at_level(logging.WARNING, logger="adworker"):
            fetch_shared(client, forged, tmp_path)
        assert not (tmp_path / SHARED_FILE).exists()
        assert f"is of study {one.id}, not {two.id}" in caplog.text
        client.tell(theirs.trial_id, 0.3, worker_id="w")


def test_updates_made_at_once_are_merged_and_none_is_lost(shared_server: ServerProcess) -> None:
    """Four workers start from version 1 and offer their updates at the same moment
    (adworker's own merging, :func:`adworker.sharing.advance_shared`): every update
    lands, the versions run 2 to 5 with no gap, and the last version is version 1 plus
    the sum of the four updates: none was lost."""
    task = "shared-merges"
    with Client(shared_server.url) as client:
        study = client.create_study(study_body("shared merges", task))
        first = client.lease("w0", tasks=[task])
        assert first is not None
        base = weights(0)
        upload(client, first, shared_weights.encode(base), "w0")
        client.advance_shared(first.trial_id, worker_id="w0", base_version=None)
        client.tell(first.trial_id, 0.0, worker_id="w0")
        jobs = [client.lease(f"w{k}", tasks=[task]) for k in range(1, 5)]
        deltas = [{name: np.full_like(a, 10.0**k) for name, a in base.items()} for k in range(4)]
        taken: list[int | None] = [None] * 4
        ready = threading.Barrier(4)

        def offer(k: int) -> None:
            job = jobs[k]
            assert job is not None and job.shared is not None and job.shared.version == 1
            mine = {name: base[name] + deltas[k][name] for name in base}
            with Client(shared_server.url) as own:
                upload(own, job, shared_weights.encode(mine), f"w{k + 1}")
                ready.wait()
                taken[k] = advance_shared(
                    own,
                    job,
                    worker_id=f"w{k + 1}",
                    mine=shared_weights.encode(mine),
                    start=shared_weights.encode(base),
                    label=f"worker {k + 1}",
                )

        threads = [threading.Thread(target=offer, args=(k,)) for k in range(4)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        assert sorted(v for v in taken if v is not None) == [2, 3, 4, 5]
        current = client.shared_controller(study.id)
        assert current is not None and current.version == 5
        last = shared_weights.decode(client.get_artifact(current.trial_id, current.artifact))
        for name, array in base.items():
            expected = array + sum(delta[name] for delta in deltas)
            np.testing.assert_allclose(last[name], expected, rtol=1e-5)
        for k, job in enumerate(jobs):
            assert job is not None
            client.tell(job.trial_id, 0.1, worker_id=f"w{k + 1}")


def test_a_version_that_does_not_load_is_replaced_by_the_next_update(
    shared_server: ServerProcess,
) -> None:
    """A study whose current version is not weights (a worker uploaded garbage): the
    next update that finds the study moved on replaces it instead of merging onto it."""
    task = "shared-corrupt"
    with Client(shared_server.url) as client:
        study = client.create_study(study_body("shared corrupt", task))
        first, second = client.lease("w1", tasks=[task]), client.lease("w2", tasks=[task])
        assert first is not None and second is not None and second.shared is None
        upload(client, first, b"not weights at all", "w1")
        client.advance_shared(first.trial_id, worker_id="w1", base_version=None)
        mine = shared_weights.encode(weights(5))
        upload(client, second, mine, "w2")
        made = advance_shared(
            client,
            second,
            worker_id="w2",
            mine=mine,
            start=shared_weights.encode(weights(4)),
            label="second",
        )
        assert made == 2
        current = client.shared_controller(study.id)
        assert current is not None and current.trial_id == second.trial_id
        stored = shared_weights.decode(client.get_artifact(second.trial_id, SHARED_ARTIFACT))
        np.testing.assert_allclose(stored["log_std"], weights(5)["log_std"].astype(np.float32))
        for job, worker in ((first, "w1"), (second, "w2")):
            client.tell(job.trial_id, 0.1, worker_id=worker)


def test_a_shared_study_is_refused_where_sharing_cannot_work(
    shared_server: ServerProcess,
) -> None:
    """A learner that cannot share (ddpg, fast), and an ASHA pruner that pauses designs:
    422 naming the problem, nothing stored."""
    body = yaml.safe_load((EXAMPLES / "multi-structure.yaml").read_text())
    with Client(shared_server.url) as client:
        before = len(client.studies())
        for learner in ("ddpg", "fast"):
            task = {"name": "stand-up", "learner": learner, "transfer": "shared"}
            with pytest.raises(
                Invalid,
                match=rf"learner '{learner}' cannot train a controller shared.*can: ppo",
            ):
                client.create_study({**body, "name": "refused", "max_trials": 5, "task": task})
        pruner = {"name": "asha", "options": {"promotion": True}}
        task = {"name": "stand-up", "learner": "ppo", "transfer": "shared"}
        with pytest.raises(Invalid, match="promotion"):
            client.create_study(
                {**body, "name": "refused", "max_trials": 5, "task": task, "pruner": pruner}
            )
        assert len(client.studies()) == before


def test_a_trial_makes_one_version_whatever_is_resent_or_retried(
    shared_server: ServerProcess,
) -> None:
    """A trial that made version 1 resends its request after another trial made version
    2 (its answer was lost): it is answered version 1, nothing moves and nothing is
    merged twice. Leased again (its lease expired before its tell), it may not replace
    the weights of the version it made."""
    task = "shared-once"
    with Client(shared_server.url) as client:
        study = client.create_study(study_body("shared once", task))
        first, second = client.lease("w1", tasks=[task]), client.lease("w2", tasks=[task])
        assert first is not None and second is not None
        upload(client, first, shared_weights.encode(weights(1)), "w1")
        assert client.advance_shared(first.trial_id, worker_id="w1", base_version=None).version == 1
        upload(client, second, shared_weights.encode(weights(2)), "w2")
        assert client.advance_shared(second.trial_id, worker_id="w2", base_version=1).version == 2
        again = client.advance_shared(first.trial_id, worker_id="w1", base_version=None)
        assert (again.version, again.trial_id) == (1, first.trial_id)
        current = client.shared_controller(study.id)
        assert current is not None and (current.version, current.trial_id) == (2, second.trial_id)
        made = client.get_artifact(first.trial_id, SHARED_ARTIFACT)

        released = httpx.post(
            f"{shared_server.url}/api/v1/trials/{first.trial_id}/release", json={}
        )
        assert released.status_code == 200, released.text
        redo = client.lease("w3", tasks=[task])
        assert redo is not None and redo.trial_id == first.trial_id
        with pytest.raises(Conflict, match="made version 1 of its study's shared controller"):
            upload(client, redo, shared_weights.encode(weights(3)), "w3")
        assert client.get_artifact(first.trial_id, SHARED_ARTIFACT) == made
        for job, worker in ((redo, "w3"), (second, "w2")):
            client.tell(job.trial_id, 0.1, worker_id=worker)


def test_a_version_whose_file_is_gone_means_the_initial_weights(
    shared_server: ServerProcess, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The version a job names has no file (its trial never uploaded one that stayed):
    the worker says so and starts from the initial weights (nothing in the job folder)."""
    with Client(shared_server.url) as client:
        client.create_study(study_body("shared gone", "shared-gone"))
        job = client.lease("w", tasks=["shared-gone"])
        assert job is not None
        pointing = job.model_copy(
            update={"shared": SharedVersion(version=1, trial_id=job.trial_id)}
        )
        with caplog.at_level(logging.WARNING, logger="adworker"):
            fetch_shared(client, pointing, tmp_path)
        assert not (tmp_path / SHARED_FILE).exists()
        assert "shared controller version 1 is not there" in caplog.text
        client.tell(job.trial_id, 0.1, worker_id="w")
