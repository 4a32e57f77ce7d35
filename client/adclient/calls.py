"""The server's calls, one HTTP request each, with Optuna-like names:
:class:`ServerCalls`, which :class:`adclient.Client` extends with study handles
(:mod:`adclient.study`, which uses these calls, so they sit below both).
Transport and retries: :mod:`adclient.transport`; export: :mod:`adclient.export`.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any, Literal
from urllib.parse import quote

from pydantic import BaseModel, ValidationError

from adclient.errors import Invalid, NotFound, UnreadableJob
from adclient.export import ExportFormat, export_csv, export_json
from adclient.objectives import as_values
from adclient.pruning import (
    CHECKPOINT_ARTIFACT,
    PauseRequest,
    ReportRequest,
    ReportResponse,
    TrialReport,
)
from adclient.schemas import (
    CURVE_ARTIFACT,
    MAX_TRIAL_PAGE,
    MAX_WORKER_PAGE,
    REPLAY_ARTIFACT,
    ArtifactInfo,
    AskResponse,
    Curve,
    HeartbeatResponse,
    Job,
    LearnerInfo,
    Note,
    Replay,
    SharedUpdate,
    SharedVersion,
    Study,
    StudyServing,
    StudySpread,
    TaskInfo,
    TellRequest,
    Trial,
    TrialAdd,
    TrialState,
    WorkerInfo,
)
from adclient.transport import API, Transport

TrialRef = Trial | int


def trial_id_of(trial: TrialRef) -> int:
    """Accept a Trial or its id wherever a trial is named."""
    return trial.id if isinstance(trial, Trial) else int(trial)


class ServerCalls(Transport):
    """Every call of one activedesign server (studies, trials, workers' jobs, artifacts,
    the task catalogue), each one request. Connection settings: :class:`Transport`."""

    # -- service ---------------------------------------------------------------------

    def health(self) -> bool:
        """True when ``/healthz`` answers 200; raises :class:`Unavailable` otherwise."""
        self.request("GET", "/healthz")
        return True

    def dashboard_url(self, study_id: int) -> str:
        """Where the study is shown in the web dashboard."""
        return f"{self.url}/#/studies/{study_id}"

    def tasks(self) -> list[TaskInfo]:
        """The tasks installed on the server (what a study's task may name), each with
        the JSON schema of its options."""
        return [TaskInfo.model_validate(item) for item in self._get_json(f"{API}/tasks")]

    def learners(self) -> list[LearnerInfo]:
        """The learners installed on the server, each with its options' JSON schema."""
        return [LearnerInfo.model_validate(item) for item in self._get_json(f"{API}/learners")]

    # -- studies ---------------------------------------------------------------------

    def study_info(self, study_id: int) -> Study:
        """The study's current record: state, counts, best value."""
        return Study.model_validate(self._get_json(f"{API}/studies/{int(study_id)}"))

    def stop_study(self, study_id: int) -> Study:
        """Stop a study: it takes no new trials; running ones may still be told."""
        data = self.request("POST", f"{API}/studies/{int(study_id)}/stop", idempotent=True).json()
        return Study.model_validate(data)

    def studies(self) -> list[Study]:
        """Every study on the server."""
        return [Study.model_validate(item) for item in self._get_json(f"{API}/studies")]

    def delete_study(self, study_id: int, *, force: bool = False) -> None:
        """Delete a study with its trials, reports and artifacts (its owner or an admin).
        Raises :class:`Conflict` while workers hold leases on its trials, unless ``force``
        (their leases are cancelled), and :class:`NotFound` once it is gone. Not resent
        when an answer is lost: a second DELETE is a 404."""
        self.request(
            "DELETE",
            f"{API}/studies/{int(study_id)}",
            params={"force": "true"} if force else None,
            idempotent=False,
        )

    def set_study_user_attrs(self, study_id: int, attrs: Mapping[str, Any]) -> Study:
        """Merge ``attrs`` into the study's user attributes (a ``None`` value deletes its
        key); returns the study."""
        data = self.request(
            "PATCH",
            f"{API}/studies/{int(study_id)}",
            json_body={"user_attrs": jsonable(attrs)},
            idempotent=True,
        ).json()
        return Study.model_validate(data)

    # -- notes -----------------------------------------------------------------------

    def study_note(self, study_id: int) -> Note:
        """The study's note (empty ``text`` where none was written)."""
        return Note.model_validate(self._get_json(f"{API}/studies/{int(study_id)}/note"))

    def set_study_note(self, study_id: int, text: str) -> Note:
        """Replace the study's note (its owner or an admin; empty text removes it)."""
        path = f"{API}/studies/{int(study_id)}/note"
        data = self.request("PUT", path, json_body={"text": text}, idempotent=True).json()
        return Note.model_validate(data)

    def trial_note(self, trial: TrialRef) -> Note:
        """The trial's note (empty ``text`` where none was written)."""
        return Note.model_validate(self._get_json(f"{API}/trials/{trial_id_of(trial)}/note"))

    def set_trial_note(self, trial: TrialRef, text: str) -> Note:
        """Replace the trial's note (its study's owner or an admin; empty text removes it)."""
        path = f"{API}/trials/{trial_id_of(trial)}/note"
        data = self.request("PUT", path, json_body={"text": text}, idempotent=True).json()
        return Note.model_validate(data)

    def trial_by_number(self, study_id: int, number: int) -> Trial | None:
        """Trial ``number`` of the study (as the dashboard and ``trials`` number them), or
        None when it has no such trial."""
        found = self._get_json(
            f"{API}/studies/{int(study_id)}/trials", params={"numbers": int(number), "limit": 1}
        )
        return Trial.model_validate(found[0]) if found else None

    def set_trial_user_attrs(
        self, trial: TrialRef, attrs: Mapping[str, Any], *, worker_id: str | None = None
    ) -> Trial:
        """Merge ``attrs`` into the trial's user attributes (a ``None`` value deletes its
        key): as the study's owner, or as the worker holding its lease (``worker_id``)."""
        body: dict[str, Any] = {"user_attrs": jsonable(attrs)}
        if worker_id is not None:
            body["worker_id"] = worker_id
        data = self.request(
            "PATCH", f"{API}/trials/{trial_id_of(trial)}", json_body=body, idempotent=True
        ).json()
        return Trial.model_validate(data)

    # -- ask / tell ------------------------------------------------------------------

    def add_trials(
        self, study_id: int, trials: Iterable[TrialAdd | Mapping[str, Any]]
    ) -> list[Trial]:
        """Hand trials to a study (its owner): each without an outcome is enqueued (the
        next ask hands it out before proposing, as Optuna's ``enqueue_trial``), each with
        a ``value`` or ``state`` is an evaluation already made (``add_trial``: a warm
        start). All are stored or none; each is checked here first (:class:`Invalid`
        naming it) and then against the study's space by the server. Not resent when an
        answer is lost (``skip_if_exists`` makes a resend harmless)."""
        bodies: list[dict[str, Any]] = []
        for index, trial in enumerate(trials):
            try:
                add = TrialAdd.model_validate(
                    jsonable(trial) if isinstance(trial, Mapping) else trial
                )
            except ValidationError as exc:
                raise Invalid(
                    None, "invalid", f"trials[{index}]: {validation_message(exc)}"
                ) from exc
            bodies.append(add.model_dump(mode="json", exclude_defaults=True))
        data = self.request(
            "POST", f"{API}/studies/{int(study_id)}/trials", json_body=bodies, idempotent=False
        ).json()
        return [Trial.model_validate(item) for item in data]

    def ask(self, study_id: int, count: int = 1) -> list[Trial]:
        """Ask the study's proposer for ``count`` new trials (1..64), now ``running``."""
        data = self.request(
            "POST",
            f"{API}/studies/{int(study_id)}/ask",
            json_body={"count": jsonable(count)},
            idempotent=False,
        ).json()
        return AskResponse.model_validate(data).trials

    def tell(
        self,
        trial: TrialRef,
        value: float | Sequence[float] | None = None,
        *,
        state: Literal["complete", "failed", "pruned"] | TrialState | str | None = None,
        message: str | None = None,
        metrics: Mapping[str, float] | None = None,
        worker_id: str | None = None,
        transfer_from: int | None = None,
    ) -> Trial:
        """Report a trial's result and return the finished trial.

        ``state`` defaults to ``complete`` when a value is given and to ``failed``
        otherwise; ``pruned`` ends a trial its pruner stopped (with ``value``, or the
        server keeps its last reported value). A study of several objectives is told a
        sequence, one value per objective (Optuna's ``study.tell(trial, [v1, v2])``).
        ``transfer_from``: the trial of the same study whose controller this one started
        from (``task.transfer``), kept as its ``info.transfer_from``.
        The body is checked here first (finite values, finite metrics), so a NaN never
        travels; such mistakes raise :class:`Invalid`. Repeating an identical tell is
        harmless; a contradicting one raises :class:`Conflict`.
        """
        values = as_values(value)
        number = None if value is None or values is not None else float(value)  # type: ignore[arg-type]
        if state is None:
            state = "complete" if number is not None or values is not None else "failed"
        state = str(state.value if isinstance(state, TrialState) else state)
        try:
            body = TellRequest(
                value=number,
                values=values,
                state=state,  # type: ignore[arg-type]
                message=message,
                worker_id=worker_id,
                metrics={str(key): float(metric) for key, metric in (metrics or {}).items()},
                transfer_from=transfer_from,
            )
        except ValidationError as exc:
            raise Invalid(None, "invalid", validation_message(exc)) from exc
        data = self.request(
            "POST",
            f"{API}/trials/{trial_id_of(trial)}/tell",
            json_body=body.model_dump(mode="json", exclude_none=True, exclude_defaults=False),
            idempotent=True,
        ).json()
        return Trial.model_validate(data)

    def trials(
        self,
        study_id: int,
        state: TrialState | str | None = None,
        *,
        offset: int = 0,
        limit: int | None = None,
    ) -> list[Trial]:
        """The study's trials in order of number, optionally only those in ``state``:
        all of them, or ``limit`` from the ``offset``-th on.

        The server answers at most ``MAX_TRIAL_PAGE`` trials a request; longer lists are
        fetched page by page, each after the last number seen (a trial that changes
        state meanwhile shifts no other out of the list).
        """
        found: list[Trial] = []
        params: dict[str, Any] = {"offset": offset}
        if state is not None:
            params["state"] = str(getattr(state, "value", state))
        while limit is None or len(found) < limit:
            wanted = MAX_TRIAL_PAGE if limit is None else min(MAX_TRIAL_PAGE, limit - len(found))
            data = self._get_json(
                f"{API}/studies/{int(study_id)}/trials", params={**params, "limit": wanted}
            )
            found += [Trial.model_validate(item) for item in data]
            if len(data) < wanted:
                break
            params.update(offset=0, after=found[-1].number + 1)
        return found

    def report(
        self, trial: TrialRef, step: int, value: float, *, worker_id: str | None = None
    ) -> bool:
        """Report a running trial's intermediate ``value`` at ``step``; returns whether
        the study's pruner would stop it there (then tell it ``state="pruned"``). A
        repeat is harmless; a finished trial or a lost lease raises :class:`Conflict`."""
        return self.report_answer(trial, step, value, worker_id=worker_id).should_stop

    def report_answer(
        self, trial: TrialRef, step: int, value: float, *, worker_id: str | None = None
    ) -> ReportResponse:
        """:meth:`report`'s whole answer: ``pause`` says a worker should pause the trial
        with a checkpoint (:meth:`pause`) rather than tell it pruned."""
        try:
            body = ReportRequest(step=int(step), value=float(value), worker_id=worker_id)
        except ValidationError as exc:
            raise Invalid(None, "invalid", validation_message(exc)) from exc
        data = self.request(
            "POST",
            f"{API}/trials/{trial_id_of(trial)}/report",
            json_body=body.model_dump(mode="json", exclude_none=True),
            idempotent=True,
        ).json()
        return ReportResponse.model_validate(data)

    def pause(
        self,
        trial: TrialRef,
        *,
        worker_id: str,
        step: int,
        checkpoint: str = CHECKPOINT_ARTIFACT,
        value: float | None = None,
        metrics: Mapping[str, float] | None = None,
        transfer_from: int | None = None,
        budget: int | None = None,
    ) -> Trial:
        """Pause a held trial at ``step`` with the checkpoint artifact it uploaded (its
        study's ASHA pruner said ``pause``); it waits for promotion, and its job then
        trains on to ``budget`` steps (default: the task's budget). A repeat is
        harmless; a lost lease raises :class:`Conflict`."""
        try:
            body = PauseRequest(
                worker_id=worker_id,
                step=int(step),
                checkpoint=checkpoint,
                value=value,
                metrics=dict(metrics or {}),
                transfer_from=transfer_from,
                budget=budget,
            )
        except ValidationError as exc:
            raise Invalid(None, "invalid", validation_message(exc)) from exc
        data = self.request(
            "POST",
            f"{API}/trials/{trial_id_of(trial)}/pause",
            json_body=body.model_dump(mode="json", exclude_none=True),
            idempotent=True,
        ).json()
        return Trial.model_validate(data)

    def shared_controller(self, study_id: int) -> SharedVersion | None:
        """The study's current shared controller (``task.transfer: shared``): its
        version and the trial whose ``SHARED_ARTIFACT`` holds its weights; None before
        its first version."""
        data = self._get_json(f"{API}/studies/{int(study_id)}/shared-controller")
        return None if data is None else SharedVersion.model_validate(data)

    def advance_shared(
        self, trial: TrialRef, *, worker_id: str, base_version: int | None
    ) -> SharedVersion:
        """Make the update the held trial uploaded as ``SHARED_ARTIFACT`` its study's next
        shared version, if the study is still at ``base_version`` (None: none yet);
        :class:`Conflict` when it moved on (merge onto the current version, upload, and
        ask again) or the lease is lost. A repeat once done answers the same version."""
        try:
            body = SharedUpdate(worker_id=worker_id, base_version=base_version)
        except ValidationError as exc:
            raise Invalid(None, "invalid", validation_message(exc)) from exc
        data = self.request(
            "POST",
            f"{API}/trials/{trial_id_of(trial)}/shared-controller",
            json_body=body.model_dump(mode="json"),
            idempotent=True,
        ).json()
        return SharedVersion.model_validate(data)

    def reports(self, trial: TrialRef) -> list[TrialReport]:
        """A trial's reported curve, in order of step."""
        data = self._get_json(f"{API}/trials/{trial_id_of(trial)}/reports")
        return [TrialReport.model_validate(item) for item in data]

    def get_trial(self, trial: TrialRef) -> Trial:
        """One trial's current record."""
        return Trial.model_validate(self._get_json(f"{API}/trials/{trial_id_of(trial)}"))

    def pareto(self, study_id: int) -> list[Trial]:
        """The study's complete, feasible trials that no other one dominates, by number
        (Optuna's ``best_trials``; for one objective, those with the best value)."""
        data = self._get_json(f"{API}/studies/{int(study_id)}/pareto")
        return [Trial.model_validate(item) for item in data]

    def best_trial(self, study_id: int) -> Trial | None:
        """The best complete (and feasible) trial, or ``None`` while there is none.

        Raises :class:`NotFound` when the study itself does not exist and
        :class:`Conflict` for a study of several objectives (see :meth:`pareto`).
        """
        try:
            return Trial.model_validate(self._get_json(f"{API}/studies/{int(study_id)}/best"))
        except NotFound:
            self.study_info(study_id)  # raises NotFound for an unknown study
            return None

    def spread(self, study_id: int) -> StudySpread:
        """Each objective's n, mean, standard deviation, min, median and max over the
        study's complete trials: for a study of one design, the spread of its repeats."""
        data = self._get_json(f"{API}/studies/{int(study_id)}/spread")
        return StudySpread.model_validate(data)

    # -- workers ---------------------------------------------------------------------

    def lease(
        self,
        worker_id: str,
        tasks: Iterable[str] | None = None,
        learners: Iterable[str] | None = None,
    ) -> Job | None:
        """Lease the next job of a managed study (of one of ``tasks`` and ``learners``,
        when given: the ones this worker can run), or ``None`` when there is no work;
        :class:`UnreadableJob` when the job leased names what this SDK does not know."""
        body: dict[str, Any] = {"worker_id": worker_id}
        if tasks is not None:
            body["tasks"] = list(tasks)
        if learners is not None:
            body["learners"] = list(learners)
        response = self.request("POST", f"{API}/jobs/lease", json_body=body, idempotent=False)
        if response.status_code == 204 or not response.content:
            return None
        data = response.json()
        try:
            return Job.model_validate(data)
        except ValidationError as exc:
            trial_id = data.get("trial_id") if isinstance(data, dict) else None
            raise UnreadableJob(
                trial_id if type(trial_id) is int else None, validation_message(exc)
            ) from exc

    def heartbeat(self, trial: TrialRef, worker_id: str) -> HeartbeatResponse:
        """Extend the lease on a trial; raises :class:`Conflict` when the lease was lost."""
        data = self.request(
            "POST",
            f"{API}/trials/{trial_id_of(trial)}/heartbeat",
            json_body={"worker_id": worker_id},
            idempotent=True,
        ).json()
        return HeartbeatResponse.model_validate(data)

    def release(self, trial: TrialRef, worker_id: str) -> Trial:
        """Give a leased trial back to the queue at once (a worker leaving mid-job);
        raises :class:`Conflict` when this worker does not hold the lease."""
        data = self.request(
            "POST",
            f"{API}/trials/{trial_id_of(trial)}/release",
            json_body={"worker_id": worker_id},
            idempotent=False,
        ).json()
        return Trial.model_validate(data)

    def workers(
        self, study_id: int | None = None, *, offset: int = 0, limit: int = MAX_WORKER_PAGE
    ) -> list[WorkerInfo]:
        """The workers that worked on a study (every worker the server has seen, when
        None), newest first, with their current leases and the tasks they serve; at most
        ``limit`` (``MAX_WORKER_PAGE`` at most) after skipping ``offset``."""
        path = "workers" if study_id is None else f"studies/{int(study_id)}/workers"
        data = self._get_json(f"{API}/{path}", params={"offset": offset, "limit": limit})
        return [WorkerInfo.model_validate(item) for item in data]

    def serving(self, study_id: int) -> StudyServing | None:
        """Whether the workers seen lately serve a study's task and learner, and what to
        start when none does; None for a study no worker runs (unmanaged, or not
        running)."""
        data = self._get_json(f"{API}/studies/{int(study_id)}/serving")
        return None if data is None else StudyServing.model_validate(data)

    # -- artifacts -------------------------------------------------------------------

    def put_artifact(
        self,
        trial: TrialRef,
        name: str,
        data: bytes,
        content_type: str = "application/octet-stream",
        *,
        worker_id: str | None = None,
    ) -> ArtifactInfo:
        """Store ``data`` as the trial's artifact ``name`` (replacing one of that name).

        A worker uploads while it holds the trial's lease and names itself with
        ``worker_id``; the owner of an asked trial names no worker."""
        response = self.request(
            "PUT",
            f"{API}/trials/{trial_id_of(trial)}/artifacts/{quote(name, safe='')}",
            params={"worker_id": worker_id} if worker_id else None,
            content=bytes(data),
            headers={"Content-Type": content_type},
        )
        return ArtifactInfo.model_validate(response.json())

    def get_artifact(self, trial: TrialRef, name: str) -> bytes:
        """The bytes of the trial's artifact ``name`` (sent as one path segment, whatever
        it holds: a name the server does not allow is a 422 naming it, never another
        path or query)."""
        path = f"{API}/trials/{trial_id_of(trial)}/artifacts/{quote(name, safe='')}"
        return self.request("GET", path, headers={"Accept": "*/*"}).content

    def trial_curve(self, trial: TrialRef) -> Curve:
        """The trial's learning curve (its worker's ``curve.json``): the training points
        and the evaluation episodes. NotFound without one; pydantic's ValidationError
        for a file that is not a curve (a ``--function`` job may upload its own)."""
        return Curve.model_validate_json(self.get_artifact(trial, CURVE_ARTIFACT))

    def trial_replay(self, trial: TrialRef) -> Replay:
        """The trial's replayable evaluation episode (its worker's ``replay.json``): the
        root's pose and the joints' positions per control step. NotFound without one."""
        return Replay.model_validate_json(self.get_artifact(trial, REPLAY_ARTIFACT))

    def artifacts(self, trial: TrialRef) -> list[ArtifactInfo]:
        """The trial's stored artifacts."""
        data = self._get_json(f"{API}/trials/{trial_id_of(trial)}/artifacts")
        return [ArtifactInfo.model_validate(item) for item in data]

    def trial_urdf(self, trial: TrialRef) -> str:
        """The URDF of a design-space trial's robot."""
        path = f"{API}/trials/{trial_id_of(trial)}/urdf"
        return self.request("GET", path, headers={"Accept": "*/*"}).text

    # -- export ----------------------------------------------------------------------

    def export(self, study_id: int, format: ExportFormat = "json") -> str:
        """The study and all its trials as text.

        ``json``: ``{"study": Study, "trials": [Trial, ...]}``, indented.
        ``csv``: one row per trial, columns ``number, id, state, value, ...`` then
        ``params_<name>``, ``metrics_<name>`` and ``user_attrs_<key>`` (nested values
        flattened with dots, lists written as JSON), in the manner of Optuna's
        ``trials_dataframe``.
        """
        info = self.study_info(study_id)
        trials = self.trials(study_id)
        if format == "json":
            return export_json(info, trials)
        if format == "csv":
            return export_csv(trials)
        raise ValueError(f"unknown export format {format!r}: use 'json' or 'csv'")


# -- small helpers ---------------------------------------------------------------------


def jsonable(value: Any) -> Any:
    """Turn pydantic models and NumPy values (scalars, arrays) nested in a body into
    plain JSON values, as a script computes params and attributes with NumPy."""
    if isinstance(value, BaseModel):
        return value.model_dump(mode="json")
    if type(value).__module__ == "numpy" and hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, Mapping):
        return {str(key): jsonable(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(item) for item in value]
    return value


def validation_message(exc: ValidationError) -> str:
    parts = []
    for error in exc.errors():
        where = ".".join(str(part) for part in error.get("loc", ()))
        msg = error.get("msg", "")
        parts.append(f"{where}: {msg}" if where else str(msg))
    return "; ".join(parts)
