"""The Python SDK: a synchronous HTTP client with Optuna-like names.

::

    from adclient import Client

    with Client("http://127.0.0.1:8000") as client:
        study = client.create_study(
            name="demo",
            direction="minimize",
            space={"type": "box", "params": [{"name": "x", "low": -5, "high": 5}]},
        )
        trial = study.ask()                      # one Trial
        study.tell(trial, value=trial.params["x"] ** 2)
        batch = study.ask(count=4)               # a list of 4 Trials
        print(study.best_trial)

Why the retries are safe: a request that never reached the server (connection
refused, connect timeout) is always retried; a 5xx or 429 answer means the server
rolled the request back, so it is retried too. A request whose answer was lost after
it was sent (read timeout, dropped connection) is retried only where repeating it is
harmless: reads, artifact uploads, heartbeats and tells (the server accepts a repeated
identical tell). ``create_study``, ``ask`` and ``lease`` are not repeated in that case
(they would create or lease a second time); they raise :class:`Unavailable` instead.
"""

from __future__ import annotations

import csv
import io
import json
import math
import random
import time
from collections.abc import Callable, Iterable, Mapping
from datetime import datetime
from typing import Any, Literal, overload

import httpx
from pydantic import BaseModel, ValidationError

from adclient import __version__
from adclient.errors import ApiError, Invalid, NotFound, Unavailable, error_class
from adclient.schemas import (
    MAX_TRIAL_PAGE,
    ArtifactInfo,
    AskResponse,
    HeartbeatResponse,
    Job,
    Study,
    StudyCreate,
    StudyState,
    TellRequest,
    Trial,
    TrialState,
    WorkerInfo,
)

API = "/api/v1"
DEFAULT_TIMEOUT = 30.0
DEFAULT_RETRIES = 5
DEFAULT_BACKOFF = 0.2
DEFAULT_MAX_BACKOFF = 5.0

ExportFormat = Literal["json", "csv"]
TrialRef = Trial | int


CLIENT_HEADER = "X-Activedesign-Client"
"""Sent with every request: a header a cross-site page cannot set without the server's
leave, so the server accepts state changes only from clients that send it (or JSON)."""


def trial_id_of(trial: TrialRef) -> int:
    """Accept a Trial or its id wherever a trial is named."""
    return trial.id if isinstance(trial, Trial) else int(trial)


def study_finished(study: Study) -> bool:
    """True once a study will change no more by itself.

    Its state left ``running``, or its trial budget is spent: every one of
    ``max_trials`` trials is complete or failed.
    """
    if study.state != StudyState.running:
        return True
    if study.max_trials is None:
        return False
    return study.n_complete + study.n_failed >= study.max_trials


class Client:
    """A connection to one activedesign server.

    ``url`` is the server's base URL (``http://host:port``). ``token`` is sent as
    ``Authorization: Bearer <token>``. ``timeout`` bounds each attempt in seconds.
    ``retries`` is how many times a failed attempt is repeated (see the module notes
    for which failures), waiting ``backoff * 2**n`` seconds (with jitter, at most
    ``max_backoff``, or the server's ``Retry-After``) before repeat ``n``.

    Use it as a context manager, or call :meth:`close`.
    """

    def __init__(
        self,
        url: str,
        token: str | None = None,
        *,
        timeout: float = DEFAULT_TIMEOUT,
        retries: int = DEFAULT_RETRIES,
        backoff: float = DEFAULT_BACKOFF,
        max_backoff: float = DEFAULT_MAX_BACKOFF,
        verify: bool | str = True,
    ) -> None:
        """``verify``: check an https server's certificate against the system's CAs (True),
        against the CA bundle file at this path (a private or self-signed CA), or not at
        all (False)."""
        if retries < 0:
            raise ValueError("retries must be >= 0")
        self.url = url.rstrip("/")
        self.retries = retries
        self.backoff = backoff
        self.max_backoff = max_backoff
        headers = {
            "User-Agent": f"adclient/{__version__}",
            "Accept": "application/json",
            CLIENT_HEADER: __version__,
        }
        if token:
            headers["Authorization"] = f"Bearer {token}"
        if isinstance(verify, str):  # httpx deprecates a path: it wants a context
            import ssl

            tls: bool | ssl.SSLContext = ssl.create_default_context(cafile=verify)
        else:
            tls = verify
        self._http = httpx.Client(
            base_url=self.url,
            headers=headers,
            timeout=httpx.Timeout(timeout, connect=min(timeout, 10.0)),
            verify=tls,
        )

    # -- lifecycle -------------------------------------------------------------------

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"Client({self.url!r})"

    # -- transport -------------------------------------------------------------------

    def request(
        self,
        method: str,
        path: str,
        *,
        json_body: Any = None,
        content: bytes | None = None,
        headers: Mapping[str, str] | None = None,
        params: Mapping[str, Any] | None = None,
        idempotent: bool | None = None,
    ) -> httpx.Response:
        """Send one request with retries; return the 2xx/3xx response or raise an ApiError.

        ``idempotent`` (default: true for GET, HEAD, PUT and DELETE) says whether a
        request whose answer was lost may be sent again.
        """
        if idempotent is None:
            idempotent = method.upper() in {"GET", "HEAD", "PUT", "DELETE"}
        kwargs: dict[str, Any] = {"headers": headers, "params": params}
        if json_body is not None:
            kwargs["json"] = json_body
        if content is not None:
            kwargs["content"] = content
        where = f"{method} {path}"
        failure: ApiError
        for attempt in range(self.retries + 1):
            delay = self._delay(attempt)
            try:
                response = self._http.request(method, path, **kwargs)
            except (httpx.ConnectError, httpx.ConnectTimeout, httpx.PoolTimeout) as exc:
                failure = Unavailable(
                    None,
                    "unreachable",
                    f"cannot reach server at {self.url} ({_reason(exc)})",
                    method=method,
                    url=path,
                )
            except httpx.TransportError as exc:
                failure = Unavailable(
                    None,
                    "no_answer",
                    f"no answer from server at {self.url} to {where} ({_reason(exc)})",
                    method=method,
                    url=path,
                )
                if not idempotent:
                    raise failure from exc
            else:
                if response.status_code < 400:
                    return response
                failure = self._error(response, method, path)
                if not _retryable_status(response.status_code):
                    raise failure
                delay = _retry_after(response, default=delay, cap=self.max_backoff)
            if attempt < self.retries:
                time.sleep(delay)
        raise failure

    def _delay(self, attempt: int) -> float:
        """Exponential backoff with 'equal jitter': between half and all of the step."""
        step = min(self.max_backoff, self.backoff * (2**attempt))
        return step * (0.5 + random.random() / 2)

    @staticmethod
    def _error(response: httpx.Response, method: str, path: str) -> ApiError:
        code: str | None = None
        detail: Any = None
        try:
            body = response.json()
        except ValueError:
            body = None
        if isinstance(body, dict) and ("error" in body or "detail" in body):
            code = body.get("error") if isinstance(body.get("error"), str) else None
            detail = body.get("detail")
        elif response.text:
            detail = response.text[:500]
        if detail is None or detail == "":
            detail = f"HTTP {response.status_code} {response.reason_phrase}".strip()
        cls = error_class(response.status_code)
        return cls(response.status_code, code, detail, method=method, url=path)

    def _get_json(self, path: str, params: Mapping[str, Any] | None = None) -> Any:
        return self.request("GET", path, params=params).json()

    # -- service ---------------------------------------------------------------------

    def health(self) -> bool:
        """True when ``/healthz`` answers 200; raises :class:`Unavailable` otherwise."""
        self.request("GET", "/healthz")
        return True

    def dashboard_url(self, study_id: int) -> str:
        """Where the study is shown in the web dashboard."""
        return f"{self.url}/#/studies/{study_id}"

    # -- studies ---------------------------------------------------------------------

    def create_study(
        self,
        spec: StudyCreate | Mapping[str, Any] | None = None,
        /,
        *,
        name: str | None = None,
        space: Any = None,
        direction: str | None = None,
        proposer: Any = None,
        task: Any = None,
        max_trials: int | None = None,
        **fields: Any,
    ) -> StudyHandle:
        """Create a study and return its handle.

        Give either a whole body (a :class:`StudyCreate` or a dict of one, e.g. read
        from YAML) or the fields as keywords; keywords override the body's fields.
        Pydantic models given as field values (``BoxSpace``, ``TaskConfig``...) are
        accepted. The server validates the body and answers :class:`Invalid` naming the
        bad field.
        """
        body: dict[str, Any]
        if spec is None:
            body = {}
        elif isinstance(spec, BaseModel):
            body = spec.model_dump(mode="json")
        elif isinstance(spec, Mapping):
            body = dict(spec)
        else:
            raise TypeError(f"create_study takes a StudyCreate or a mapping, not {type(spec)}")
        given = {
            "name": name,
            "space": space,
            "direction": direction,
            "proposer": proposer,
            "task": task,
            "max_trials": max_trials,
            **fields,
        }
        body.update({key: value for key, value in given.items() if value is not None})
        body = _jsonable(body)
        data = self.request("POST", f"{API}/studies", json_body=body, idempotent=False).json()
        info = Study.model_validate(data)
        return StudyHandle(self, info.id, info)

    def get_study(self, study_id: int) -> StudyHandle:
        """The handle of an existing study (raises :class:`NotFound` if there is none)."""
        info = self.study_info(study_id)
        return StudyHandle(self, info.id, info)

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

    # -- ask / tell ------------------------------------------------------------------

    def ask(self, study_id: int, count: int = 1) -> list[Trial]:
        """Ask the study's proposer for ``count`` new trials (1..64), now ``running``."""
        data = self.request(
            "POST",
            f"{API}/studies/{int(study_id)}/ask",
            json_body={"count": count},
            idempotent=False,
        ).json()
        return AskResponse.model_validate(data).trials

    def tell(
        self,
        trial: TrialRef,
        value: float | None = None,
        *,
        state: Literal["complete", "failed"] | TrialState | str | None = None,
        message: str | None = None,
        metrics: Mapping[str, float] | None = None,
        worker_id: str | None = None,
    ) -> Trial:
        """Report a trial's result and return the finished trial.

        ``state`` defaults to ``complete`` when a value is given and to ``failed``
        otherwise. The body is checked here first (a finite value, finite metrics), so
        a NaN never travels; such mistakes raise :class:`Invalid`. Repeating an
        identical tell is harmless; a contradicting one raises :class:`Conflict`.
        """
        if value is not None:
            value = float(value)  # numpy scalars and ints alike
        if state is None:
            state = "complete" if value is not None else "failed"
        state = str(state.value if isinstance(state, TrialState) else state)
        try:
            body = TellRequest(
                value=value,
                state=state,  # type: ignore[arg-type]
                message=message,
                worker_id=worker_id,
                metrics={str(key): float(metric) for key, metric in (metrics or {}).items()},
            )
        except ValidationError as exc:
            raise Invalid(None, "invalid", _validation_message(exc)) from exc
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

    def get_trial(self, trial: TrialRef) -> Trial:
        """One trial's current record."""
        return Trial.model_validate(self._get_json(f"{API}/trials/{trial_id_of(trial)}"))

    def best_trial(self, study_id: int) -> Trial | None:
        """The best complete trial, or ``None`` while no trial is complete.

        Raises :class:`NotFound` when the study itself does not exist.
        """
        try:
            return Trial.model_validate(self._get_json(f"{API}/studies/{int(study_id)}/best"))
        except NotFound:
            self.study_info(study_id)  # raises NotFound for an unknown study
            return None

    # -- workers ---------------------------------------------------------------------

    def lease(self, worker_id: str, tasks: Iterable[str] | None = None) -> Job | None:
        """Lease the next job of a managed study (of one of ``tasks``, when given: the
        tasks this worker can run), or ``None`` when there is no work."""
        body: dict[str, Any] = {"worker_id": worker_id}
        if tasks is not None:
            body["tasks"] = list(tasks)
        response = self.request("POST", f"{API}/jobs/lease", json_body=body, idempotent=False)
        if response.status_code == 204 or not response.content:
            return None
        return Job.model_validate(response.json())

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

    def workers(self, study_id: int) -> list[WorkerInfo]:
        """The workers that worked on a study, with their current leases."""
        data = self._get_json(f"{API}/studies/{int(study_id)}/workers")
        return [WorkerInfo.model_validate(item) for item in data]

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
            f"{API}/trials/{trial_id_of(trial)}/artifacts/{name}",
            params={"worker_id": worker_id} if worker_id else None,
            content=bytes(data),
            headers={"Content-Type": content_type},
        )
        return ArtifactInfo.model_validate(response.json())

    def get_artifact(self, trial: TrialRef, name: str) -> bytes:
        """The bytes of the trial's artifact ``name``."""
        path = f"{API}/trials/{trial_id_of(trial)}/artifacts/{name}"
        return self.request("GET", path, headers={"Accept": "*/*"}).content

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
        ``params_<name>`` and ``metrics_<name>`` (nested params flattened with dots,
        lists written as JSON), in the manner of Optuna's ``trials_dataframe``.
        """
        info = self.study_info(study_id)
        trials = self.trials(study_id)
        if format == "json":
            return export_json(info, trials)
        if format == "csv":
            return export_csv(trials)
        raise ValueError(f"unknown export format {format!r}: use 'json' or 'csv'")


class StudyHandle:
    """One study on the server, with Optuna-like methods.

    ``ask()`` returns one :class:`Trial`; ``ask(count=n)`` returns a list of ``n``
    (a list even for ``n == 1``), so the return type follows from the call.
    """

    def __init__(self, client: Client, study_id: int, info: Study | None = None) -> None:
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
    def dashboard_url(self) -> str:
        return self.client.dashboard_url(self.id)

    @overload
    def ask(self) -> Trial: ...

    @overload
    def ask(self, count: int) -> list[Trial]: ...

    def ask(self, count: int | None = None) -> Trial | list[Trial]:
        """``ask()``: one new trial. ``ask(count=n)``: a list of ``n`` new trials."""
        trials = self.client.ask(self.id, 1 if count is None else count)
        return trials[0] if count is None else trials

    def tell(
        self,
        trial: TrialRef,
        value: float | None = None,
        *,
        state: Literal["complete", "failed"] | TrialState | str | None = None,
        message: str | None = None,
        metrics: Mapping[str, float] | None = None,
    ) -> Trial:
        """Report a result; see :meth:`Client.tell`."""
        return self.client.tell(trial, value, state=state, message=message, metrics=metrics)

    @property
    def best_trial(self) -> Trial | None:
        """The best complete trial, or ``None`` while none is complete."""
        return self.client.best_trial(self.id)

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
        func: Callable[[Trial], float | None],
        n_trials: int,
        *,
        catch: Iterable[type[BaseException]] | type[BaseException] = (),
        callbacks: Iterable[Callable[[StudyHandle, Trial], None]] = (),
    ) -> list[Trial]:
        """Ask, evaluate ``func(trial)`` and tell, ``n_trials`` times; return the told trials.

        A value that is ``None`` or not finite is told as a failed trial. An exception
        from ``func`` is told as a failed trial with its message; it is then swallowed
        if its class is in ``catch``, re-raised otherwise (as Optuna does).
        """
        caught = tuple(catch) if not isinstance(catch, type) else (catch,)
        told: list[Trial] = []
        for _ in range(n_trials):
            trial = self.ask()
            try:
                value = func(trial)
            except Exception as exc:
                message = f"{type(exc).__name__}: {exc}"
                told.append(self.tell(trial, state="failed", message=message[:10_000]))
                if isinstance(exc, caught):
                    continue
                raise
            if value is None or not math.isfinite(float(value)):
                finished = self.tell(trial, state="failed", message=f"objective returned {value!r}")
            else:
                finished = self.tell(trial, float(value))
            told.append(finished)
            for callback in callbacks:
                callback(self, finished)
        return told

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

    def workers(self) -> list[WorkerInfo]:
        return self.client.workers(self.id)

    def export(self, format: ExportFormat = "json") -> str:
        return self.client.export(self.id, format)


# -- export helpers --------------------------------------------------------------------

_CSV_FIELDS = [
    "number",
    "id",
    "state",
    "value",
    "worker_id",
    "attempts",
    "created_at",
    "started_at",
    "finished_at",
    "duration_s",
    "message",
]


def export_json(study: Study, trials: list[Trial]) -> str:
    payload = {
        "study": study.model_dump(mode="json"),
        "trials": [trial.model_dump(mode="json") for trial in trials],
    }
    return json.dumps(payload, indent=2) + "\n"


def export_csv(trials: list[Trial]) -> str:
    rows: list[dict[str, Any]] = []
    param_columns: dict[str, None] = {}
    metric_columns: dict[str, None] = {}
    for trial in sorted(trials, key=lambda t: t.number):
        row: dict[str, Any] = {
            "number": trial.number,
            "id": trial.id,
            "state": trial.state.value,
            "value": _cell(trial.value),
            "worker_id": trial.worker_id or "",
            "attempts": trial.attempts,
            "created_at": _cell(trial.created_at),
            "started_at": _cell(trial.started_at),
            "finished_at": _cell(trial.finished_at),
            "duration_s": _duration(trial.started_at, trial.finished_at),
            "message": trial.message or "",
        }
        for key, value in _flatten(trial.params):
            column = f"params_{key}"
            param_columns.setdefault(column)
            row[column] = _cell(value)
        for key, metric in trial.metrics.items():
            column = f"metrics_{key}"
            metric_columns.setdefault(column)
            row[column] = _cell(metric)
        rows.append(row)
    out = io.StringIO()
    writer = csv.DictWriter(
        out,
        fieldnames=[*_CSV_FIELDS, *param_columns, *metric_columns],
        restval="",
        lineterminator="\n",
    )
    writer.writeheader()
    writer.writerows(rows)
    return out.getvalue()


def _flatten(value: Mapping[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    items: list[tuple[str, Any]] = []
    for key, item in value.items():
        name = f"{prefix}{key}"
        if isinstance(item, Mapping) and item:
            items.extend(_flatten(item, f"{name}."))
        else:
            items.append((name, item))
    return items


def _cell(value: Any) -> Any:
    if value is None:
        return ""
    if isinstance(value, datetime):
        return value.isoformat()
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, list | dict | tuple):
        return json.dumps(value, separators=(",", ":"))
    return value


def _duration(start: datetime | None, end: datetime | None) -> str:
    if start is None or end is None:
        return ""
    return f"{(end - start).total_seconds():.3f}"


# -- small helpers ---------------------------------------------------------------------


def _jsonable(value: Any) -> Any:
    """Turn pydantic models nested in a body into plain JSON values."""
    if isinstance(value, BaseModel):
        return value.model_dump(mode="json")
    if isinstance(value, Mapping):
        return {str(key): _jsonable(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(item) for item in value]
    return value


def _retryable_status(status_code: int) -> bool:
    return status_code >= 500 or status_code == 429


def _retry_after(response: httpx.Response, *, default: float, cap: float) -> float:
    header = response.headers.get("Retry-After")
    if header is None:
        return default
    try:
        seconds = float(header)
    except ValueError:
        return default
    if not math.isfinite(seconds) or seconds < 0:
        return default
    return min(seconds, cap)


def _reason(exc: Exception) -> str:
    text = str(exc).strip()
    return text or type(exc).__name__


def _validation_message(exc: ValidationError) -> str:
    parts = []
    for error in exc.errors():
        where = ".".join(str(part) for part in error.get("loc", ()))
        msg = error.get("msg", "")
        parts.append(f"{where}: {msg}" if where else str(msg))
    return "; ".join(parts)
