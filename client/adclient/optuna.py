"""An Optuna sampler backed by a service study, for an unchanged Optuna script::

    import optuna
    from adclient import Client
    from adclient.optuna import ServiceSampler

    sampler = ServiceSampler(Client("http://127.0.0.1:8000"), proposer="qei")
    study = optuna.create_study(study_name="quadratic", sampler=sampler)
    study.optimize(objective, n_trials=50, n_jobs=2)

What it promises (docs/optuna.md says it for users):

- The relative search space is Optuna's intersection search space (the params every
  finished trial suggested with one distribution), less single-valued ones and those a
  box study cannot hold (:mod:`adclient.optuna_space`). Once it is known, the sampler
  attaches to a box study of that space and the Optuna study's directions: the running
  study of that name (``study_name``, default the Optuna study's) with the same space
  and directions, else a new one. Finished Optuna trials not yet in it are added to it
  as evaluations, so it learns from the whole history.
- Each Optuna trial's relative params come from one ask of that study; its end is told
  back (complete with its value(s), failed, pruned with its last value). An Optuna
  trial that did not use the asked params is told failed, saying so.
- Other params (outside the relative space, the first trial's, those an enqueued
  trial does not fix) come from ``independent_sampler`` (default ``RandomSampler``),
  with one :class:`IndependentSamplingWarning` per param where the space is known.
  An enqueued trial's evaluation is added to the study.
- Pending points are the service's: each ask is a trial running there until told, so
  threads (``n_jobs``) and processes share one study and its pending trials.
- It says, once per service study, which one it uses (Optuna's logger, as Optuna says
  "A new study created"): created, or attached to with how many trials it holds. An
  attach to a study holding trials this Optuna study did not give it (an earlier run's
  history, another process's) is a warning, since that history is the service study's
  best and progress. The service study stays running when ``optimize`` returns (an
  Optuna study never ends: another ``optimize`` or a rerun continues it), and the
  message says so and how to stop it.

Needs Optuna (``pip install activedesign[optuna]``); ``import adclient`` never imports it.
"""

from __future__ import annotations

import json
import math
import threading
import warnings
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any, cast
from uuid import uuid4

from optuna.logging import get_logger
from optuna.samplers import BaseSampler, RandomSampler
from optuna.search_space import IntersectionSearchSpace
from optuna.trial import TrialState
from pydantic import BaseModel

from adclient.objectives import MAX_OBJECTIVES
from adclient.optuna_space import RelativeSpace
from adclient.schemas import Study, StudyState
from adclient.study import StudyHandle

if TYPE_CHECKING:
    from optuna.distributions import BaseDistribution
    from optuna.study import Study as OptunaStudy
    from optuna.trial import FrozenTrial

    from adclient.client import Client

__all__ = ["IndependentSamplingWarning", "ServiceSampler"]

TRIAL_ATTR = "adclient:trial"
"""An Optuna trial's system attribute: ``{"study", "trial"}``, the service trial that
holds it, and ``asked``, the params an ask gave it (absent for an added evaluation)."""
ADDED_ATTR = "adclient:added"
"""Prefix of the Optuna study's system attributes ``adclient:added:<study>:<token>``:
the numbers of finished trials added to service study ``<study>`` at one attach."""
ADD_CHUNK = 1000
LOGGER = get_logger("optuna.adclient")
"""Under Optuna's root logger, so it shows as Optuna's own lines do (INFO by default) and
``optuna.logging.set_verbosity`` quiets it."""


class IndependentSamplingWarning(UserWarning):
    """A param was sampled by the independent sampler, not the service study."""


class ServiceSampler(BaseSampler):
    """An Optuna sampler whose relative params come from a service study's proposer.

    ``client``: an :class:`adclient.Client`. ``study_name``: the service study's name
    (default: the Optuna study's); a rerun finds its study by this name, space and
    directions. ``proposer``: the new study's proposer, a name (``"qei"``, ``"tpe"``,
    ``"random"``, ...) or a config mapping; default the server's. ``seed`` seeds the
    proposer (unless its config has one) and the default independent sampler.
    ``independent_sampler``: for params outside the relative space (default
    ``RandomSampler(seed)``). ``warn_independent_sampling``: warn once per such param.
    """

    def __init__(
        self,
        client: Client,
        *,
        study_name: str | None = None,
        proposer: str | Mapping[str, Any] | BaseModel | None = None,
        seed: int | None = None,
        independent_sampler: BaseSampler | None = None,
        warn_independent_sampling: bool = True,
    ) -> None:
        self._client = client
        self._study_name = study_name
        self._proposer = _proposer_config(proposer, seed)
        self._independent = independent_sampler or RandomSampler(seed=seed)
        self._warn = warn_independent_sampling
        self._intersection = IntersectionSearchSpace()
        self._lock = threading.Lock()
        self._studies: dict[str, StudyHandle] = {}
        self._current: tuple[RelativeSpace, StudyHandle] | None = None
        self._left_out: dict[str, str] = {}
        self._finishing: list[tuple[FrozenTrial, TrialState, Sequence[float] | None]] = []
        self._warned: set[str] = set()

    @property
    def service_study(self) -> StudyHandle | None:
        """The service study of the latest relative space (None before the first ask)."""
        return None if self._current is None else self._current[1]

    # -- Optuna's sampler interface --------------------------------------------------

    def reseed_rng(self) -> None:
        self._independent.reseed_rng()

    def before_trial(self, study: OptunaStudy, trial: FrozenTrial) -> None:
        _directions(study)  # more objectives than a service study takes: refused here
        self._independent.before_trial(study, trial)

    def infer_relative_search_space(
        self, study: OptunaStudy, trial: FrozenTrial
    ) -> dict[str, BaseDistribution]:
        with self._lock:
            space = self._intersection.calculate(study)
        kept, left = RelativeSpace.expressible(
            {name: dist for name, dist in space.items() if not dist.single()}
        )
        self._left_out.update(left)
        return kept

    def sample_relative(
        self,
        study: OptunaStudy,
        trial: FrozenTrial,
        search_space: dict[str, BaseDistribution],
    ) -> dict[str, Any]:
        if not search_space:
            return {}
        if search_space.keys() & (trial.system_attrs.get("fixed_params") or {}).keys():
            return {}  # an enqueued trial: its params win, and it is added once finished
        space = RelativeSpace.of(search_space)
        handle = self._attach(study, space)
        asked = handle.ask()
        params = space.to_optuna(asked)
        _mark(study, trial, {"study": handle.id, "trial": asked.id, "asked": params})
        return params

    def sample_independent(
        self,
        study: OptunaStudy,
        trial: FrozenTrial,
        param_name: str,
        param_distribution: BaseDistribution,
    ) -> Any:
        if (
            self._warn
            and param_name not in self._warned
            and not trial.system_attrs.get("fixed_params")
            and study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
        ):
            self._warned.add(param_name)
            why = self._left_out.get(param_name)
            reason = (
                f"the service study cannot hold it ({why})"
                if why is not None
                else "it is not suggested with one distribution in every finished trial "
                "(a dynamic search space)"
            )
            warnings.warn(
                f"param {param_name!r} of trial {trial.number} is sampled by "
                f"{type(self._independent).__name__}, not the service study: {reason}. "
                "ServiceSampler(warn_independent_sampling=False) keeps this quiet.",
                IndependentSamplingWarning,
                stacklevel=2,
            )
        return self._independent.sample_independent(study, trial, param_name, param_distribution)

    def after_trial(
        self,
        study: OptunaStudy,
        trial: FrozenTrial,
        state: TrialState,
        values: Sequence[float] | None,
    ) -> None:
        self._independent.after_trial(study, trial, state, values)
        mark = trial.system_attrs.get(TRIAL_ATTR)
        if mark is not None and "asked" in mark:
            unused = sorted(
                name
                for name, value in mark["asked"].items()
                if name not in trial.params or trial.params[name] != value
            )
            if unused:
                outcome: dict[str, Any] = {
                    "state": "failed",
                    "message": f"Optuna trial {trial.number} did not use the asked "
                    f"{', '.join(unused)} (a dynamic search space, or fixed params)",
                }
            else:
                outcome = _outcome(trial.number, state, values)
            self._client.tell(
                mark["trial"],
                outcome.get("value", outcome.get("values")),
                state=outcome.get("state", "complete"),
                message=outcome.get("message"),
            )
            return
        if mark is not None:
            return
        with self._lock:  # an attach in progress adds this trial, or it is added here
            if self._current is None:
                # its state is stored after this call: the first attach adds it from here
                self._finishing.append((trial, state, values))
                return
            space, handle = self._current
        body = _evaluation(space, trial, state, values)
        if body is not None:  # an enqueued trial, or one sampled before the space was known
            added = self._client.add_trials(handle.id, [body])[0]
            _mark(study, trial, {"study": handle.id, "trial": added.id})

    # -- the service study -----------------------------------------------------------

    def _attach(self, study: OptunaStudy, space: RelativeSpace) -> StudyHandle:
        """The service study of ``space``: found or created once, with the history added."""
        directions = _directions(study)
        key = json.dumps([space.box, directions], sort_keys=True)
        with self._lock:
            handle = self._studies.get(key)
            if handle is None:
                handle, found = self._find_or_create(study, space, directions)
                held = self._add_history(study, space, handle)
                self._studies[key] = handle
                _say_attached(handle, found, held)
            self._current = (space, handle)
            return handle

    def _find_or_create(
        self, study: OptunaStudy, space: RelativeSpace, directions: list[str]
    ) -> tuple[StudyHandle, Study | None]:
        """The service study and, where it was found running, its state when found."""
        name = self._study_name or study.study_name
        found = self._matching(name, space, directions)
        if found:
            return StudyHandle(self._client, found[0].id, found[0]), found[0]
        objectives: dict[str, Any] = (
            {"direction": directions[0]} if len(directions) == 1 else {"directions": directions}
        )
        metadata: dict[str, Any] = {"optuna_study": study.study_name}
        if space.renamed:
            metadata["optuna_names"] = space.renamed
        created = self._client.create_study(
            name=name,
            space=space.box,
            proposer=self._proposer,
            metadata=metadata,
            **objectives,
        )
        # Another process may have created the same study meanwhile: the first one wins.
        first = min(self._matching(name, space, directions), key=lambda s: s.id, default=None)
        if first is None or first.id == created.id:
            return created, None
        created.delete()
        return StudyHandle(self._client, first.id, first), first

    def _matching(self, name: str, space: RelativeSpace, directions: list[str]) -> list[Study]:
        """Running studies of this name, box space and directions, oldest first."""
        return sorted(
            (
                found
                for found in self._client.studies()
                if found.name == name
                and found.state == StudyState.running
                and found.task is None
                and found.objectives is None
                and found.space.model_dump(mode="json") == space.box
                and ([d.value for d in found.directions] or [found.direction.value]) == directions
            ),
            key=lambda found: found.id,
        )

    def _add_history(
        self, study: OptunaStudy, space: RelativeSpace, handle: StudyHandle
    ) -> tuple[int, int]:
        """Add the finished Optuna trials the service study does not hold yet; how many
        of this Optuna study's trials it held before, and how many were added."""
        trials = study.get_trials(deepcopy=False)
        held = {
            trial.number
            for trial in trials
            if (trial.system_attrs.get(TRIAL_ATTR) or {}).get("study") == handle.id
        }
        prefix = f"{ADDED_ATTR}:{handle.id}:"
        for key, value in study._storage.get_study_system_attrs(study._study_id).items():
            if key.startswith(prefix):
                held.update(value)
        finished = {
            trial.number: (trial, trial.state, trial.values)
            for trial in trials
            if trial.state.is_finished()
        }
        for trial, state, values in self._finishing:
            finished.setdefault(trial.number, (trial, state, values))
        self._finishing.clear()
        bodies: list[dict[str, Any]] = []
        numbers: list[int] = []
        for number, (trial, state, values) in sorted(finished.items()):
            body = None if number in held else _evaluation(space, trial, state, values)
            if body is not None:
                bodies.append(body)
                numbers.append(number)
        for start in range(0, len(bodies), ADD_CHUNK):
            self._client.add_trials(handle.id, bodies[start : start + ADD_CHUNK])
            study._storage.set_study_system_attr(
                study._study_id,
                f"{prefix}{uuid4().hex}",
                numbers[start : start + ADD_CHUNK],
            )
        return len(held), len(bodies)


def _say_attached(handle: StudyHandle, found: Study | None, held: tuple[int, int]) -> None:
    """Say once which service study the sampler uses and what it holds (module docstring)."""
    own, added = held
    where = f"service study {handle.id} {handle.name!r} ({handle.dashboard_url})"
    history = f"; {_count(added, 'finished Optuna trial')} added to it" if added else ""
    stays = (
        "It stays running when optimize() returns: another optimize() or a rerun of this "
        "name and space continues it"
    )
    stop = f"`adclient stop {handle.id}` (or sampler.service_study.stop()) ends it."
    if found is None:
        LOGGER.info(f"ServiceSampler created {where}{history}. {stays}; {stop}")
        return
    others = max(found.n_trials - own, 0)
    if others == 0:
        LOGGER.info(
            f"ServiceSampler attached to running {where}, which holds "
            f"{_count(found.n_trials, 'trial')}, all this Optuna study's{history}. "
            f"{stays}; {stop}"
        )
        return
    LOGGER.warning(
        f"ServiceSampler attached to running {where}, which holds "
        f"{_count(found.n_trials, 'trial')}, {others} of them not this Optuna study's (an "
        f"earlier run's or another process's): its best and progress count them{history}. "
        f"{stays}. For a fresh study pass another study_name, or stop this one: {stop}"
    )


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def _mark(study: OptunaStudy, trial: FrozenTrial, mark: dict[str, Any]) -> None:
    """Keep in the running Optuna trial which service trial holds it (:data:`TRIAL_ATTR`)."""
    study._storage.set_trial_system_attr(trial._trial_id, TRIAL_ATTR, cast(Any, mark))


def _proposer_config(
    proposer: str | Mapping[str, Any] | BaseModel | None, seed: int | None
) -> dict[str, Any] | None:
    if proposer is None:
        config: dict[str, Any] = {}
    elif isinstance(proposer, str):
        config = {"name": proposer}
    elif isinstance(proposer, BaseModel):
        config = proposer.model_dump(mode="json", exclude_unset=True)
    else:
        config = dict(proposer)
    if seed is not None:
        config.setdefault("seed", seed)
    return config or None


def _directions(study: OptunaStudy) -> list[str]:
    directions = [direction.name.lower() for direction in study.directions]
    if len(directions) > MAX_OBJECTIVES:
        raise ValueError(
            f"the Optuna study has {len(directions)} objectives; a service study "
            f"optimises at most {MAX_OBJECTIVES}"
        )
    return directions


def _outcome(number: int, state: TrialState, values: Sequence[float] | None) -> dict[str, Any]:
    """An Optuna trial's end as a tell's (or an added trial's) fields."""
    finite = values is not None and all(math.isfinite(v) for v in values)
    if state == TrialState.COMPLETE:
        if values is not None and finite:
            return {"value": values[0]} if len(values) == 1 else {"values": list(values)}
        return {"state": "failed", "message": f"Optuna trial {number}: values {values} not finite"}
    if state == TrialState.PRUNED:
        pruned: dict[str, Any] = {"state": "pruned"}
        if values is not None and finite and len(values) == 1:
            pruned["value"] = values[0]
        return pruned
    return {"state": "failed", "message": f"Optuna trial {number} failed"}


def _evaluation(
    space: RelativeSpace,
    trial: FrozenTrial,
    state: TrialState,
    values: Sequence[float] | None,
) -> dict[str, Any] | None:
    """A finished Optuna trial as an added trial of ``space``'s study, or None when its
    params do not cover the space."""
    params = space.to_service(trial.params, trial.distributions)
    if params is None:
        return None
    return {"params": params, **_outcome(trial.number, state, values)}
