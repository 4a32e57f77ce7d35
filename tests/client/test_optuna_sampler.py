"""adclient.optuna's ServiceSampler: real Optuna studies, unchanged, against a real
``adserver`` on a SQLite file."""

from __future__ import annotations

import ast
import logging
import math
import re
import subprocess
import sys
import threading
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path

import optuna
import pytest
from optuna.distributions import CategoricalDistribution, FloatDistribution, IntDistribution
from optuna.storages import JournalStorage
from optuna.storages.journal import JournalFileBackend

from adclient import Client
from adclient.optuna import TRIAL_ATTR, IndependentSamplingWarning, ServiceSampler
from adclient.optuna_space import RelativeSpace, box_param, service_names
from adclient.schemas import BoxParam, Study, Trial
from adclient.testing.servers import ServerProcess

optuna.logging.set_verbosity(optuna.logging.WARNING)
GUIDE = Path(__file__).resolve().parents[2] / "docs" / "optuna.md"
RANDOM = {"name": "random", "seed": 5}
CHEAP_QEI = {"num_restarts": 2, "raw_samples": 64, "maxiter": 20}
KINDS = {"a": 1.0, "b": 0.0, "c": 2.0}


def quadratic(trial: optuna.Trial) -> float:
    """An Optuna objective as people write them: a float, an int, a log float and a
    categorical; 0 at x=1, n=3, lr=0.01, kind=b."""
    x = trial.suggest_float("x", -5.0, 5.0)
    n = trial.suggest_int("n", 0, 10)
    lr = trial.suggest_float("lr", 1e-4, 1.0, log=True)
    kind = trial.suggest_categorical("kind", ["a", "b", "c"])
    return (x - 1.0) ** 2 + (n - 3) ** 2 + (math.log10(lr) + 2.0) ** 2 + KINDS[kind]


def service_trials(sampler: ServiceSampler) -> list[Trial]:
    assert sampler.service_study is not None
    return sampler.service_study.trials


def studies_named(client: Client, name: str) -> list[Study]:
    return [study for study in client.studies() if study.name == name]


def told_params(trial: optuna.trial.FrozenTrial) -> dict[str, object]:
    return {name: trial.params[name] for name in ("kind", "lr", "n", "x")}


def test_each_distribution_the_service_cannot_hold_says_why() -> None:
    held = box_param("lr", FloatDistribution(1e-4, 1.0, log=True))
    assert isinstance(held, BoxParam) and held.log and held.type == "float"
    stepped = box_param("n", IntDistribution(0, 10, step=2))
    assert isinstance(stepped, BoxParam) and stepped.step == 2
    assert box_param("c", CategoricalDistribution([None, "on"])) == "a choice is None"
    assert "of one type" in str(box_param("c", CategoricalDistribution([1, "a"])))
    assert "1001 choices" in str(box_param("c", CategoricalDistribution(list(range(1001)))))
    assert "too wide" in str(box_param("x", FloatDistribution(-1e308, 1e308)))
    assert "2**53" in str(box_param("n", IntDistribution(0, 2**60)))
    many = {f"x{i:03d}": FloatDistribution(0.0, 1.0) for i in range(257)}
    kept, left = RelativeSpace.expressible(many)
    assert len(kept) == 256 and left == {"x256": "a box study holds at most 256 params"}


def test_names_outside_the_services_pattern_are_renamed_alike_on_every_run() -> None:
    names = ["x", "lr/encoder", "lr_encoder", "_hidden"]
    renamed = {"x": "x", "lr_encoder": "lr_encoder", "_hidden": "p_hidden"}
    assert service_names(names) == {**renamed, "lr/encoder": "lr_encoder-2"}
    assert service_names(reversed(names)) == service_names(names)


def test_an_unchanged_quadratic_ends_near_its_optimum_and_the_service_holds_it(
    client: Client,
) -> None:
    sampler = ServiceSampler(client, proposer="tpe", seed=1)
    study = optuna.create_study(study_name="quadratic", sampler=sampler)
    with warnings.catch_warnings():
        warnings.simplefilter("error", IndependentSamplingWarning)  # a static space: none
        study.optimize(quadratic, n_trials=60)

    assert study.best_value < 0.5
    assert study.best_params["n"] == 3 and study.best_params["kind"] == "b"
    service = sampler.service_study
    assert service is not None and service.name == "quadratic"
    assert service.info.direction == "minimize" and service.info.proposer.name == "tpe"
    params = {p.name: p for p in service.info.space.params}  # type: ignore[union-attr]
    assert (params["x"].type, params["x"].low, params["x"].high) == ("float", -5.0, 5.0)
    assert (params["n"].type, params["n"].low, params["n"].high) == ("int", 0, 10)
    assert params["lr"].log and params["lr"].low == 1e-4
    assert params["kind"].choices == ["a", "b", "c"]
    # trial 0 was sampled before the space was known (added to the study), every later
    # one asked the study: each Optuna trial is one service trial, with its value
    held = {trial.id: trial for trial in service_trials(sampler)}
    assert len(held) == 60
    trials = study.trials
    assert TRIAL_ATTR not in trials[0].system_attrs
    for trial in trials[1:]:
        mark = trial.system_attrs[TRIAL_ATTR]
        assert mark["study"] == service.id and mark["asked"] == trial.params
        assert held[mark["trial"]].params == trial.params
        assert held[mark["trial"]].value == trial.value
    first = next(t for t in held.values() if t.info.get("source") == "added")
    assert first.params == told_params(trials[0]) and first.value == trials[0].value
    assert service.best_value == study.best_value


def test_params_the_service_cannot_hold_or_that_change_are_sampled_independently(
    client: Client,
) -> None:
    def objective(trial: optuna.Trial) -> float:
        x = trial.suggest_float("x", 0.0, 1.0)
        odd = trial.suggest_categorical("odd", [None, "on"])  # None: no box param holds it
        named = trial.suggest_float("lr/encoder", 0.1, 1.0)  # renamed for the service
        extra = trial.suggest_int("extra", 0, 5) if trial.number % 2 else 0  # dynamic
        return x + (odd is None) + named + extra

    sampler = ServiceSampler(client, proposer=RANDOM, seed=2)
    study = optuna.create_study(study_name="independent", sampler=sampler)
    with pytest.warns(IndependentSamplingWarning) as caught:
        study.optimize(objective, n_trials=6)

    why = {str(w.message).split("'")[1]: str(w.message) for w in caught}
    assert sorted(why) == ["extra", "odd"] and len(caught) == 2  # once per param
    assert "cannot hold it" in why["odd"] and "None" in why["odd"]
    assert "dynamic search space" in why["extra"]
    service = sampler.service_study
    assert service is not None
    space = service.info.space
    assert [p.name for p in space.params] == ["lr_encoder", "x"]  # type: ignore[union-attr]
    assert service.info.metadata["optuna_names"] == {"lr_encoder": "lr/encoder"}
    for trial in study.trials[1:]:
        asked = trial.system_attrs[TRIAL_ATTR]["asked"]
        assert asked == {"lr/encoder": trial.params["lr/encoder"], "x": trial.params["x"]}
    assert all(t.state.value == "complete" for t in service_trials(sampler))


def test_failed_pruned_and_infinite_trials_are_told_as_such(client: Client) -> None:
    def objective(trial: optuna.Trial) -> float:
        x = trial.suggest_float("x", -1.0, 1.0)
        if trial.number == 2:
            raise RuntimeError("the simulator crashed")
        if trial.number == 3:
            trial.report(0.75, step=1)
            raise optuna.TrialPruned()
        if trial.number == 4:
            return math.inf
        return x**2

    sampler = ServiceSampler(client, proposer=RANDOM)
    study = optuna.create_study(study_name="failures", sampler=sampler)
    study.optimize(objective, n_trials=6, catch=(RuntimeError,))

    by_number = {t.number: t for t in study.trials}
    states = [by_number[n].state.name for n in range(6)]
    assert states == ["COMPLETE", "COMPLETE", "FAIL", "PRUNED", "COMPLETE", "COMPLETE"]
    held = {t.id: t for t in service_trials(sampler)}
    told = {n: held[by_number[n].system_attrs[TRIAL_ATTR]["trial"]] for n in range(1, 6)}
    assert told[2].state == "failed" and told[2].message == "Optuna trial 2 failed"
    assert told[3].state == "pruned" and told[3].value == 0.75
    assert told[4].state == "failed" and "not finite" in (told[4].message or "")
    assert told[5].state == "complete" and told[5].value == by_number[5].value
    assert not any(t.state == "running" for t in held.values())


def test_enqueued_trials_keep_their_params_and_are_added(client: Client) -> None:
    def objective(trial: optuna.Trial) -> float:
        return trial.suggest_float("x", -2.0, 2.0) + trial.suggest_int("n", 0, 4)

    sampler = ServiceSampler(client, proposer=RANDOM)
    study = optuna.create_study(study_name="enqueued", sampler=sampler)
    study.optimize(objective, n_trials=2)
    study.enqueue_trial({"x": 0.25, "n": 3})
    study.enqueue_trial({"x": -1.5})  # n from the independent sampler
    study.optimize(objective, n_trials=3)

    trials = study.trials
    assert trials[2].params == {"x": 0.25, "n": 3} and trials[3].params["x"] == -1.5
    held = {t.id: t for t in service_trials(sampler)}
    assert len(held) == 5
    for trial in trials[2:4]:
        mark = trial.system_attrs[TRIAL_ATTR]
        assert "asked" not in mark  # no ask was spent on it
        added = held[mark["trial"]]
        assert added.info["source"] == "added"
        assert added.params == trial.params and added.value == trial.value
    assert "asked" in trials[4].system_attrs[TRIAL_ATTR]


def test_a_rerun_resumes_the_service_study_by_name(client: Client, tmp_path) -> None:
    storage = JournalStorage(JournalFileBackend(str(tmp_path / "optuna.log")))

    def run(n_trials: int) -> ServiceSampler:
        sampler = ServiceSampler(client, study_name="resumed", proposer=RANDOM)
        study = optuna.create_study(
            study_name="resume", storage=storage, sampler=sampler, load_if_exists=True
        )
        study.optimize(quadratic, n_trials=n_trials)
        return sampler

    said: list[logging.LogRecord] = []
    handler = logging.Handler(logging.INFO)
    handler.emit = said.append  # type: ignore[method-assign]
    logger = logging.getLogger("optuna.adclient")
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    try:
        first = run(4)
        second = run(3)
    finally:
        logger.removeHandler(handler)
        logger.setLevel(logging.NOTSET)

    assert first.service_study is not None and second.service_study is not None
    assert second.service_study.id == first.service_study.id
    assert [s.id for s in studies_named(client, "resumed")] == [first.service_study.id]
    held = service_trials(second)
    optuna_trials = optuna.load_study(study_name="resume", storage=storage).trials
    assert len(held) == len(optuna_trials) == 7  # the history was not added twice
    assert sorted(t.value for t in held) == sorted(t.value for t in optuna_trials)  # type: ignore[misc]
    # every trial of the rerun asked the study: its space was known from the history
    assert all("asked" in t.system_attrs[TRIAL_ATTR] for t in optuna_trials[4:])
    # the rerun's study held only this Optuna study's trials: said, not warned
    assert [record.levelno for record in said] == [logging.INFO, logging.INFO]
    assert "created" in said[0].getMessage()
    assert "which holds 4 trials, all this Optuna study's" in said[1].getMessage()


def test_threads_and_processes_share_one_service_study(client: Client) -> None:
    sampler = ServiceSampler(client, proposer=RANDOM)
    study = optuna.create_study(study_name="parallel", sampler=sampler)
    study.optimize(quadratic, n_trials=10, n_jobs=2)

    held = service_trials(sampler)
    assert len(held) == 10 and all(t.state == "complete" for t in held)
    assert sorted(t.value for t in held) == sorted(t.value for t in study.trials)  # type: ignore[misc]

    # two Optuna studies (as two processes would have) on one service study by name
    samplers = [ServiceSampler(client, study_name="shared", proposer=RANDOM) for _ in range(2)]
    studies = [optuna.create_study(sampler=s) for s in samplers]
    threads = [
        threading.Thread(target=s.optimize, args=(quadratic,), kwargs={"n_trials": 6})
        for s in studies
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    shared = studies_named(client, "shared")
    assert len(shared) == 1
    assert {s.service_study.id for s in samplers if s.service_study} == {shared[0].id}
    assert shared[0].n_complete == 12


class StoringLate(optuna.storages.InMemoryStorage):
    """Optuna's in-memory storage that runs ``meanwhile`` as it stores a trial's end: after
    the sampler's ``after_trial``, as another thread may run between the two."""

    meanwhile: Callable[[], object] | None = None

    def set_trial_state_values(
        self, trial_id: int, state: optuna.trial.TrialState, values: Sequence[float] | None = None
    ) -> bool:
        hook, self.meanwhile = self.meanwhile, None
        if hook is not None:
            hook()
        return super().set_trial_state_values(trial_id, state, values)


def test_a_trial_that_ends_while_the_study_is_attached_is_added(client: Client) -> None:
    storage = StoringLate()
    sampler = ServiceSampler(client, proposer=RANDOM)
    study = optuna.create_study(study_name="late", storage=storage, sampler=sampler)
    first, second = study.ask(), study.ask()
    for trial in (first, second):
        trial.suggest_float("x", 0.0, 1.0)  # no trial has finished: both independent
    study.tell(second, 1.0)
    third = study.ask()
    # the third trial asks (and attaches the study) after the first's after_trial, before
    # its end is stored: the first is neither finished in storage nor told by then
    storage.meanwhile = lambda: third.suggest_float("x", 0.0, 1.0)
    study.tell(first, 0.5)
    study.tell(third, 0.25)

    held = service_trials(sampler)
    assert sorted(t.value for t in held) == [0.25, 0.5, 1.0]  # type: ignore[type-var]
    assert {t.params["x"] for t in held} == {t.params["x"] for t in study.trials}


def test_pending_trials_are_the_services_own(client: Client) -> None:
    """Trials open in Optuna are running service trials: the proposer sees them as
    pending and proposes elsewhere (past its start, qei never repeats an observed or
    pending point of a discrete space while others remain)."""

    def objective(trial: optuna.Trial) -> float:
        return (trial.suggest_int("n", 0, 5) - 2) ** 2

    sampler = ServiceSampler(client, proposer={"name": "qei", "n_initial": 2, "options": CHEAP_QEI})
    study = optuna.create_study(study_name="pending", sampler=sampler)
    study.optimize(objective, n_trials=3)
    observed = {trial.params["n"] for trial in study.trials}
    open_trials = [study.ask() for _ in range(3)]
    picked = [trial.suggest_int("n", 0, 5) for trial in open_trials]

    assert len(set(picked)) == 3 and not set(picked) & observed
    service = sampler.service_study
    assert service is not None and service.info.n_running == 3
    for trial in open_trials:
        study.tell(trial, objective(trial))
    assert service.info.n_running == 0 and service.info.n_complete == 6


def test_directions_come_from_the_optuna_study(client: Client) -> None:
    def objective(trial: optuna.Trial) -> tuple[float, float]:
        x = trial.suggest_float("x", 0.0, 1.0)
        return x, (1.0 - x) ** 2

    sampler = ServiceSampler(client, proposer=RANDOM)
    study = optuna.create_study(
        study_name="two", directions=["minimize", "maximize"], sampler=sampler
    )
    study.optimize(objective, n_trials=4)
    service = sampler.service_study
    assert service is not None
    assert [d.value for d in service.info.directions] == ["minimize", "maximize"]
    told = sorted(tuple(t.values or ()) for t in service_trials(sampler))
    assert told == sorted(tuple(t.values) for t in study.trials)

    five = optuna.create_study(directions=["minimize"] * 5, sampler=ServiceSampler(client))
    with pytest.raises(ValueError, match="5 objectives; a service study optimises at most 4"):
        five.optimize(lambda trial: (trial.suggest_float("x", 0, 1),) * 5, n_trials=1)


def test_a_space_that_changes_gets_a_service_study_of_its_own(client: Client) -> None:
    high = {"x": 1.0}

    def objective(trial: optuna.Trial) -> float:
        return trial.suggest_float("x", 0.0, high["x"]) + trial.suggest_float("y", 0.0, 1.0)

    sampler = ServiceSampler(client, study_name="changing", proposer=RANDOM)
    study = optuna.create_study(sampler=sampler)
    study.optimize(objective, n_trials=3)
    before = sampler.service_study
    high["x"] = 2.0  # x's range changes: only y stays in every trial with one distribution
    with pytest.warns(IndependentSamplingWarning, match="'x'"):
        study.optimize(objective, n_trials=3)
    after = sampler.service_study

    assert before is not None and after is not None and after.id != before.id
    assert {s.id for s in studies_named(client, "changing")} == {before.id, after.id}
    assert [p.name for p in after.info.space.params] == ["y"]  # type: ignore[union-attr]
    # trial 3 still asked the first study (x's new range holds the asked x); from trial
    # 4 on the space is y alone: the new study learned trials 0 to 3 and was asked after
    assert before.info.n_running == 0 and before.info.n_complete == 4
    assert after.info.n_complete == 6
    assert study.trials[3].system_attrs[TRIAL_ATTR]["study"] == before.id
    assert study.trials[5].system_attrs[TRIAL_ATTR]["study"] == after.id


def test_the_guides_script_runs_as_written(server: ServerProcess, client: Client) -> None:
    code = re.search(r"```python\n(.*?)```", GUIDE.read_text(), re.S).group(1)  # type: ignore[union-attr]
    code = code.replace("http://127.0.0.1:8000", server.url)
    code = code.replace('study_name="quadratic"', 'study_name="guide"')  # a study of its own
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    best = ast.literal_eval(done.stdout.strip().splitlines()[-1])
    assert set(best) == {"x", "n", "lr", "kind"}
    (held,) = studies_named(client, "guide")
    assert held.n_complete == 30 and held.proposer.name == "tpe"


RERUN_SCRIPT = """
import optuna
from adclient import Client
from adclient.optuna import ServiceSampler

def objective(trial):
    return (trial.suggest_float("x", -5.0, 5.0) - 1.0) ** 2

sampler = ServiceSampler(Client({url!r}), proposer={{"name": "random", "seed": 3}})
study = optuna.create_study(study_name="rerun", sampler=sampler)
study.optimize(objective, n_trials=5)
"""


def test_a_script_says_which_service_study_it_created_or_attached_to(
    server: ServerProcess, client: Client
) -> None:
    """Optuna's default logging (a script as users run it, twice): the first run says it
    created its study, the second that it attached to one holding the first's 5 trials,
    a warning, each once; both say the study stays running and how to stop it."""
    script = RERUN_SCRIPT.format(url=server.url)

    def run() -> str:
        done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
        assert done.returncode == 0, done.stderr
        return done.stderr

    first, second = run(), run()
    (held,) = studies_named(client, "rerun")
    assert held.n_trials == 10 and held.state == "running"
    where = f"service study {held.id} 'rerun' ({client.dashboard_url(held.id)})"
    (created,) = [line for line in first.splitlines() if "ServiceSampler" in line]
    assert created.startswith("[I ") and f"ServiceSampler created {where}" in created
    assert "1 finished Optuna trial added to it" in created  # trial 0, sampled before
    (attached,) = [line for line in second.splitlines() if "ServiceSampler" in line]
    assert attached.startswith("[W ")
    assert f"attached to running {where}, which holds 5 trials, 5 of them not" in attached
    for line in (created, attached):
        assert "stays running when optimize() returns" in line
        assert f"`adclient stop {held.id}`" in line
