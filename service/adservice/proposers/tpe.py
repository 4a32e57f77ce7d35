"""Optuna's TPE sampler as a proposer (a baseline users know).

Each ask builds a throw-away in-memory Optuna study, adds the history as frozen
trials (completed ones with their value, failed ones as FAIL, pending ones as
RUNNING so that TPE's constant liar keeps new samples away from them), and asks
``count`` trials; each asked trial stays RUNNING, so a batch is spread the same
way. The sampler is seeded from ``(seed, n_issued)``.

Start: the first ``n_startup`` trials (counted by ``n_issued``) come from the
study's Sobol sequence, where ``n_startup = max(n_initial, options
["n_startup_trials"] or 10)``: 10 is Optuna's own default for TPE, which needs that
many points before its density estimates mean anything. ``options`` may also set
``multivariate`` (default true), ``constant_liar`` (default true) and
``n_ei_candidates`` (default 24).

Typed params (``request.box``) are given to Optuna as its own distributions (an int
as ``IntDistribution`` with its step or log scale, a stepped float as a stepped
``FloatDistribution``, a log float with ``log=True``, a categorical as
``CategoricalDistribution`` of its choices), so TPE models each in its kind: a
categorical by its own per-choice weights, not as an ordered number. The history's
vectors are decoded into params for it and its answers encoded back.

Several objectives (``request.objectives``) make the study Optuna's multi-objective
one (every direction ``maximize``, the columns being oriented so), whose TPE splits
the trials by non-domination rank and hypervolume contribution. Outcome constraints
(``request.slacks``) are Optuna's own (Optuna's constrained TPE, as with
``constraints_func``): each completed trial carries its slacks as its constraint
values (<= 0 satisfied), and TPE ranks infeasible trials below every feasible one,
by their total violation. Failed trials stay FAIL (TPE ignores them; they are not
taken as infeasible), pending ones RUNNING. The reference point is TPE's own
(``request.ref_point`` is not used).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
from pydantic import Field

from adservice.proposers.base import Proposal, ProposalRequest, ProposerOptions
from adservice.proposers.qei import columns_of
from adservice.proposers.simple import derived_seed, scale_to_bounds, sobol_points

if TYPE_CHECKING:
    from optuna.distributions import BaseDistribution

    from adclient.boxspace import BoxEncoding


def _param_names(dim: int) -> list[str]:
    return [f"x{i:03d}" for i in range(dim)]


def _typed_distributions(box: BoxEncoding) -> dict[str, BaseDistribution]:
    """Each typed param as Optuna's distribution of its kind."""
    from optuna.distributions import (
        CategoricalDistribution,
        FloatDistribution,
        IntDistribution,
    )

    distributions: dict[str, BaseDistribution] = {}
    for param in box.params:
        if param.type == "categorical":
            distributions[param.name] = CategoricalDistribution(param.choices or [])
            continue
        assert param.low is not None and param.high is not None
        if param.type == "int":
            distributions[param.name] = IntDistribution(
                int(param.low), int(param.high), log=param.log, step=int(param.step or 1)
            )
        else:
            distributions[param.name] = FloatDistribution(
                float(param.low), float(param.high), log=param.log, step=param.step
            )
    return distributions


def _constraints_func(slacks: np.ndarray | None) -> dict[str, Any]:
    """TPESampler's keyword for constraints: none with Optuna 5, which reads each
    trial's own constraint values; with Optuna 4 a ``constraints_func`` reading them
    from the trial's system attributes, where ``_constraint_values`` put them."""
    if slacks is None or _optuna_has_trial_constraints():
        return {}

    def constraints(trial: Any) -> tuple[float, ...]:
        return tuple(trial.system_attrs[_CONSTRAINTS_KEY])

    return {"constraints_func": constraints}


def _constraint_values(slack: np.ndarray | None) -> dict[str, Any]:
    """``create_trial``'s keyword for one trial's slacks (see ``_constraints_func``)."""
    if slack is None:
        return {}
    if _optuna_has_trial_constraints():
        return {"constraints": {f"c{j}": float(v) for j, v in enumerate(slack)}}
    return {"system_attrs": {_CONSTRAINTS_KEY: tuple(float(v) for v in slack)}}


_CONSTRAINTS_KEY = "constraints"
"""Where Optuna 4's samplers keep a trial's constraint values."""


def _optuna_has_trial_constraints() -> bool:
    """Optuna 5 stores constraint values on the trial (``create_trial(constraints=)``)."""
    import inspect

    from optuna.trial import create_trial

    return "constraints" in inspect.signature(create_trial).parameters


class TPEOptions(ProposerOptions):
    n_startup_trials: int = Field(default=10, ge=0, le=1000)
    multivariate: bool = True
    constant_liar: bool = True
    n_ei_candidates: int = Field(default=24, ge=1, le=10_000)


class TPEProposer:
    """Sobol start, then Optuna's (multivariate, constant-liar) TPE."""

    name: ClassVar[str] = "tpe"
    needs_history: ClassVar[bool] = True
    multi_objective: ClassVar[bool] = True
    constrained: ClassVar[bool] = True
    options_model: ClassVar[type[ProposerOptions]] = TPEOptions

    def propose(self, request: ProposalRequest) -> Proposal:
        import optuna
        from optuna.distributions import FloatDistribution
        from optuna.trial import TrialState, create_trial

        options = TPEOptions.model_validate(request.options)
        dim = request.dim
        bounds = np.asarray(request.bounds, dtype=np.float64)
        n_startup = max(request.n_initial, options.n_startup_trials)
        n_sobol = min(max(n_startup - request.n_issued, 0), request.count)
        rows: list[np.ndarray] = []
        info: list[dict[str, Any]] = []
        if n_sobol:
            unit = sobol_points(dim, request.seed, request.n_issued, n_sobol)
            rows.extend(scale_to_bounds(unit, bounds))
            info.extend(
                {
                    "proposer": self.name,
                    "method": "sobol-initial",
                    "sobol_index": request.n_issued + i,
                }
                for i in range(n_sobol)
            )
        if n_sobol == request.count:
            return Proposal(candidates=np.array(rows), info=info)

        box = request.box
        params: Callable[[np.ndarray], dict[str, Any]]
        vector_of: Callable[[dict[str, Any]], np.ndarray]
        distributions: dict[str, BaseDistribution]
        if box is not None:
            distributions = _typed_distributions(box)
            params, vector_of = box.decode, box.encode
        else:
            names = _param_names(dim)
            distributions = {
                name: FloatDistribution(float(bounds[0, i]), float(bounds[1, i]))
                for i, name in enumerate(names)
            }

            def params(vector: np.ndarray) -> dict[str, Any]:
                clipped = np.clip(vector, bounds[0], bounds[1])
                return {name: float(clipped[i]) for i, name in enumerate(names)}

            def vector_of(values: dict[str, Any]) -> np.ndarray:
                return np.array([values[name] for name in names])

        optuna.logging.set_verbosity(optuna.logging.WARNING)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            X = np.asarray(request.X, dtype=np.float64).reshape(-1, dim)
            y = np.asarray(request.y, dtype=np.float64).reshape(-1)
            values = y[:, None]
            if request.objectives is not None:
                values = columns_of(request.objectives, len(X))
            slacks = request.slacks
            if slacks is not None:
                slacks = columns_of(slacks, len(X))
            sampler = optuna.samplers.TPESampler(
                seed=derived_seed(request.seed, request.n_issued),
                n_startup_trials=0,
                multivariate=options.multivariate,
                constant_liar=options.constant_liar,
                n_ei_candidates=options.n_ei_candidates,
                **_constraints_func(slacks),
            )
            study = optuna.create_study(directions=["maximize"] * values.shape[1], sampler=sampler)
            trials = []
            for number, vector in enumerate(X):
                row = values[number]
                slack = None if slacks is None else slacks[number]
                if not (
                    np.all(np.isfinite(vector))
                    and np.all(np.isfinite(row))
                    and (slack is None or np.all(np.isfinite(slack)))
                ):
                    continue
                trials.append(
                    create_trial(
                        params=params(vector),
                        distributions=distributions,
                        values=[float(v) for v in row],
                        **_constraint_values(slack),
                    )
                )
            for state, vectors in (
                (TrialState.FAIL, request.failed),
                (TrialState.RUNNING, request.pending),
            ):
                for vector in np.asarray(vectors, dtype=np.float64).reshape(-1, dim):
                    if np.all(np.isfinite(vector)):
                        trials.append(
                            create_trial(
                                state=state, params=params(vector), distributions=distributions
                            )
                        )
            study.add_trials(trials)
            n_complete = sum(1 for t in trials if t.state == TrialState.COMPLETE)
            for _ in range(request.count - n_sobol):
                trial = study.ask(distributions)
                rows.append(vector_of(trial.params))
                info.append({"proposer": self.name, "method": "tpe", "n_complete": n_complete})
        candidates = np.clip(np.array(rows), bounds[0], bounds[1])
        return Proposal(candidates=candidates, info=info)
