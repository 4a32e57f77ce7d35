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

The calls, one request each: :mod:`adclient.calls`; transport and retries:
:mod:`adclient.transport`; the study handle: :mod:`adclient.study`; export:
:mod:`adclient.export`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from pydantic import BaseModel

from adclient.calls import ServerCalls, TrialRef, jsonable, trial_id_of
from adclient.schemas import Study, StudyCreate
from adclient.study import StudyHandle, study_finished
from adclient.transport import API

__all__ = ["Client", "StudyHandle", "TrialRef", "study_finished", "trial_id_of"]


class Client(ServerCalls):
    """A connection to one activedesign server: its calls (:class:`ServerCalls`) and
    handles of its studies. Connection settings: :class:`adclient.transport.Transport`."""

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
            body = spec.model_dump(mode="json", exclude_unset=True)
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
        body = jsonable(body)
        data = self.request("POST", f"{API}/studies", json_body=body, idempotent=False).json()
        info = Study.model_validate(data)
        return StudyHandle(self, info.id, info)

    def get_study(self, study_id: int) -> StudyHandle:
        """The handle of an existing study (raises :class:`NotFound` if there is none)."""
        info = self.study_info(study_id)
        return StudyHandle(self, info.id, info)
