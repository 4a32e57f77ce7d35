"""A study on the server, with Optuna-like methods: ask, tell, optimize, best_trial."""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING, Any, Literal, cast, overload

from pydantic import PrivateAttr

from adclient.errors import Conflict
from adclient.export import ExportFormat
from adclient.objectives import as_values
from adclient.pruning import TrialPruned
from adclient.schemas import Study, StudySpread, StudyState, Trial, TrialState, WorkerInfo

if TYPE_CHECKING:
    from adclient.calls import ServerCalls, TrialRef


def study_finished(study: Study) -> bool:
    """True once a study will change no more by itself.

    Its state left ``running``, or its trial budget is spent: every one of
    ``max_trials`` trials is complete, failed or pruned.
    """
    if study.state != StudyState.running:
        return True
    if study.max_trials is None:
        return False
    return study.n_complete + study.n_failed + study.n_pruned >= study.max_trials


class LiveTrial(Trial):
    """A trial asked through a :class:`StudyHandle`: while it runs it can report
    intermediate values, as Optuna's ``trial.report`` / ``trial.should_prune``::

        for step in range(0, 10_000, 1000):
            if trial.report(step, evaluate(model)):
                raise TrialPruned()   # study.optimize tells it pruned
    """

    _client: ServerCalls | None = PrivateAttr(default=None)
    _should_stop: bool = PrivateAttr(default=False)

    @classmethod
    def bound(cls, trial: Trial, client: ServerCalls) -> LiveTrial:
        live = cls.model_validate(trial.model_dump())
        live._client = client
        return live

    def report(self, step: int, value: float) -> bool:
        """Report ``value`` at ``step``; returns (and keeps in :attr:`should_stop`)
        whether the study's pruner would stop the trial here."""
        if self._client is None:
            raise RuntimeError("this trial is not bound to a client: ask it from a study")
        self._should_stop = self._client.report(self, step, value)
        return self._should_stop

    def set_user_attr(self, key: str, value: Any) -> None:
        """Store ``value`` (JSON) under ``key`` in the trial's user attributes, as
        Optuna's ``trial.set_user_attr``; ``None`` deletes the key."""
        if self._client is None:
            raise RuntimeError("this trial is not bound to a client: ask it from a study")
        self.user_attrs = self._client.set_trial_user_attrs(self, {key: value}).user_attrs

    @property
    def should_stop(self) -> bool:
        """The answer to the last :meth:`report` (False before any)."""
        return self._should_stop

    def should_prune(self) -> bool:
        """Optuna's name for :attr:`should_stop`."""
        return self._should_stop


class StudyHandle:
    """One study on the server, with Optuna-like methods.

    ``ask()`` returns one :class:`Trial`; ``ask(count=n)`` returns a list of ``n``
    (a list even for ``n == 1``), so the return type follows from the call.
    """

    def __init__(self, client: ServerCalls, study_id: int, info: Study | None = None) -> None:
        self.client = client
        self.id = int(study_id)
        self._info = info

    def __repr__(self) -> str:
        name = f" {self._info.name!r}" if self._info is not None else ""
        return f"<StudyHandle {self.id}{name}>"

    @property
    def info(self) -> Study:
        """The study's record, fetched fresh from the server on each access."""
        return self.refresh()

    def refresh(self) -> Study:
        self._info = self.client.study_info(self.id)
        return self._info

    @property
    def cached_info(self) -> Study:
        """The last fetched record (fetched once if never)."""
        return self._info if self._info is not None else self.refresh()

    @property
    def name(self) -> str:
        return self.cached_info.name

    @property
    def direction(self) -> str:
        return self.cached_info.direction.value

    @property
    def user_attrs(self) -> dict[str, Any]:
        """The study's user attributes, fetched fresh."""
        return self.info.user_attrs

    def set_user_attr(self, key: str, value: Any) -> None:
        """Store ``value`` (JSON) under ``key`` in the study's user attributes, as
        Optuna's ``study.set_user_attr``; ``None`` deletes the key."""
        self._info = self.client.set_study_user_attrs(self.id, {key: value})

    @property
    def dashboard_url(self) -> str:
        return self.client.dashboard_url(self.id)

    @overload
    def ask(self) -> LiveTrial: ...

    @overload
    def ask(self, count: int) -> list[LiveTrial]: ...

    def ask(self, count: int | None = None) -> LiveTrial | list[LiveTrial]:
        """``ask()``: one new trial. ``ask(count=n)``: a list of ``n`` new trials. Each
        can :meth:`LiveTrial.report` intermediate values while it runs."""
        asked = self.client.ask(self.id, 1 if count is None else count)
        trials = [LiveTrial.bound(trial, self.client) for trial in asked]
        return trials[0] if count is None else trials

    def enqueue_trial(self, params: Mapping[str, Any], *, skip_if_exists: bool = False) -> Trial:
        """Queue ``params`` for evaluation: the next ask hands this trial out before
        proposing (for a managed study, a worker leases it), as Optuna's
        ``enqueue_trial``; with ``skip_if_exists`` a trial of the same params already in
        the study (failed ones aside) is returned instead."""
        return self.client.add_trials(
            self.id, [{"params": dict(params), "skip_if_exists": skip_if_exists}]
        )[0]

    def add_trial(
        self,
        params: Mapping[str, Any],
        value: float | Sequence[float] | None = None,
        *,
        state: Literal["complete", "failed", "pruned"] | None = None,
        message: str | None = None,
        metrics: Mapping[str, float] | None = None,
    ) -> Trial:
        """Store an evaluation made elsewhere (Optuna's ``add_trial``): it counts in the
        study's best and its proposer learns from it. ``state`` defaults to complete; a
        study of several objectives takes a sequence of values."""
        body: dict[str, Any] = {"params": dict(params), "state": state or "complete"}
        values = as_values(value)
        if values is not None:
            body["values"] = values
        else:
            body["value"] = value
        if message is not None:
            body["message"] = message
        if metrics:
            body["metrics"] = dict(metrics)
        return self.client.add_trials(self.id, [body])[0]

    def tell(
        self,
        trial: TrialRef,
        value: float | Sequence[float] | None = None,
        *,
        state: Literal["complete", "failed", "pruned"] | TrialState | str | None = None,
        message: str | None = None,
        metrics: Mapping[str, float] | None = None,
    ) -> Trial:
        """Report a result; see :meth:`Client.tell`."""
        return self.client.tell(trial, value, state=state, message=message, metrics=metrics)

    @property
    def best_trial(self) -> Trial | None:
        """The best complete (and feasible) trial, or ``None`` while there is none; a
        study of several objectives raises :class:`Conflict`: see :attr:`best_trials`."""
        return self.client.best_trial(self.id)

    @property
    def best_trials(self) -> list[Trial]:
        """The Pareto front: complete, feasible trials no other one dominates."""
        return self.client.pareto(self.id)

    @property
    def spread(self) -> StudySpread:
        """How the complete trials' values spread, per objective (for a study of one
        design, its repeats): see :meth:`Client.spread`."""
        return self.client.spread(self.id)

    @property
    def best_value(self) -> float | None:
        best = self.best_trial
        return None if best is None else best.value

    @property
    def best_params(self) -> dict[str, Any] | None:
        best = self.best_trial
        return None if best is None else best.params

    @property
    def trials(self) -> list[Trial]:
        """Every trial, in order of number."""
        return self.client.trials(self.id)

    def get_trials(self, state: TrialState | str | None = None) -> list[Trial]:
        """The trials in ``state`` (all when ``None``)."""
        return self.client.trials(self.id, state)

    def optimize(
        self,
        func: Callable[[LiveTrial], float | Sequence[float] | None],
        n_trials: int | None = None,
        *,
        n_jobs: int = 1,
        timeout: float | None = None,
        catch: Iterable[type[Exception]] | type[Exception] = (),
        callbacks: Iterable[Callable[[StudyHandle, Trial], None]] = (),
    ) -> list[Trial]:
        """Ask, evaluate ``func(trial)`` and tell, as Optuna's ``Study.optimize`` does;
        return the told trials in the order they were told.

        ``n_trials``: how many trials to run (None: until ``timeout``, or until the study
        takes no more). ``n_jobs`` threads evaluate at once (-1: one per CPU).
        ``timeout``: no trial starts after this many seconds; running ones finish.
        A value that is ``None`` or not finite is told as a failed trial;
        :class:`~adclient.pruning.TrialPruned` raised after ``trial.report(step, value)``
        said to stop is told as pruned. An exception
        from ``func`` is told as a failed trial with its message; it is then swallowed if
        its class is in ``catch``, else re-raised once the running trials are told (no
        new ones start). ``callbacks(study, trial)`` run after every trial told, failed
        ones included, except the one whose exception is re-raised.
        """
        caught = (catch,) if isinstance(catch, type) else tuple(catch)
        jobs = (os.cpu_count() or 1) if n_jobs == -1 else n_jobs
        if jobs < 1:
            raise ValueError(f"n_jobs must be >= 1 or -1, not {n_jobs}")
        deadline = None if timeout is None else time.monotonic() + timeout
        lock = threading.Lock()
        stop = threading.Event()
        told: list[Trial] = []
        started = 0

        def claim() -> bool:
            nonlocal started
            with lock:
                over = (n_trials is not None and started >= n_trials) or (
                    deadline is not None and time.monotonic() >= deadline
                )
                if over or stop.is_set():
                    return False
                started += 1
                return True

        def work() -> None:
            while claim():
                try:
                    trial = self.ask()
                except Conflict:
                    if n_trials is None:  # the study is full or stopped: done
                        stop.set()
                        return
                    raise
                try:
                    finished = self._run(func, trial, caught)
                except BaseException:
                    stop.set()
                    raise
                with lock:
                    told.append(finished)
                for callback in callbacks:
                    callback(self, finished)

        if jobs == 1:
            work()
        else:
            with ThreadPoolExecutor(jobs, thread_name_prefix=f"study-{self.id}") as pool:
                futures = [pool.submit(work) for _ in range(jobs)]
            for future in futures:
                future.result()  # the first error, if any
        return told

    def _run(
        self,
        func: Callable[[LiveTrial], float | Sequence[float] | None],
        trial: LiveTrial,
        caught: tuple[type, ...],
    ) -> Trial:
        """Evaluate one trial and tell its result; re-raise what ``catch`` does not name."""
        try:
            value = func(trial)
        except TrialPruned as pruned:
            return self.tell(trial, pruned.value, state="pruned")
        except BaseException as exc:
            message = f"{type(exc).__name__}: {exc}"[:10_000]
            finished = self.tell(trial, state="failed", message=message)
            if isinstance(exc, caught):
                return finished
            raise
        values = as_values(value)
        told: float | list[float] | None = values
        if values is None and value is not None:
            told = float(cast(float, value))  # numpy scalars and ints alike
        finite = [told] if isinstance(told, float) else told
        if not finite or not all(math.isfinite(v) for v in finite):
            return self.tell(trial, state="failed", message=f"objective returned {value!r}")
        return self.tell(trial, told)

    def wait(
        self,
        *,
        poll: float = 2.0,
        timeout: float | None = None,
        on_update: Callable[[Study], None] | None = None,
    ) -> Study:
        """Poll until the study is finished (see :func:`study_finished`); return its record.

        ``on_update`` sees every polled record (for progress bars). Raises
        :class:`TimeoutError` after ``timeout`` seconds, when one is given.
        """
        started = time.monotonic()
        while True:
            info = self.refresh()
            if on_update is not None:
                on_update(info)
            if study_finished(info):
                return info
            if timeout is not None and time.monotonic() - started >= timeout:
                raise TimeoutError(f"study {self.id} still running after {timeout} s")
            time.sleep(poll)

    def stop(self) -> Study:
        """Stop the study: no new trials are proposed or leased."""
        self._info = self.client.stop_study(self.id)
        return self._info

    def delete(self, *, force: bool = False) -> None:
        """Delete the study and everything it holds; see :meth:`Client.delete_study`."""
        self.client.delete_study(self.id, force=force)

    def workers(self) -> list[WorkerInfo]:
        return self.client.workers(self.id)

    def export(self, format: ExportFormat = "json") -> str:
        return self.client.export(self.id, format)
