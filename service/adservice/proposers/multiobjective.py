"""qei's model phase for several objectives and for outcome constraints.

Imported only when such a proposal is computed (it imports torch and BoTorch). The
entry point is ``optimise_outcomes``, called by ``qei`` where its single-objective
model phase would run; the Sobol start, the fallbacks, the duplicate checks, the
time and memory budgets and the info common to every candidate stay qei's.

Model: one GP per outcome (each objective, each constraint's slack), each exactly
the single-objective model of ``gpfit.fit_outcome`` (``gpmodel.design_kernel``, so
design spaces of several structures and typed box params work unchanged; its own
fit cache entries and warm start), gathered in a BoTorch ``ModelListGP``.

Acquisition, greedy over the batch (each chosen candidate joins the pending points
of the next, as BoTorch's sequential greedy optimisation does), maximised by
``acquisition.maximise`` (the structure held discrete, typed params on their grid):

- Several objectives, ``options["acquisition"]`` ``analytic`` (the default):
  ``AnalyticLogEHVI``, the exact expected hypervolume improvement of one candidate
  over the observed feasible front, in log space, weighted by the probability of
  feasibility, with the pending points as Kriging believers. Each greedy step is one
  candidate and the GPs are independent, so the expectation that qLogNEHVI estimates
  by Monte Carlo over draws of the candidate has a closed form, whose cost does not
  grow with draws: at n = 80 observations of DTLZ2 (a front of 38, d = 6) an ask took
  0.43 s of CPU against 24 s for qLogNEHVI (bench/mo_asklatency.py). What it gives up:
  the front is the observations (for a noisy study, the posterior means at them), not
  integrated over their noise as qLogNEHVI's, and pending points are believed at
  their means rather than drawn jointly.
- Several objectives, ``acquisition: mc``: ``qLogNoisyExpectedHypervolumeImprovement``
  (qLogNEHVI, Daulton et al. 2021, Ament et al. 2023) with the pending points as
  ``X_pending`` (cached box decompositions), over a baseline of the observed points that are
  Pareto-optimal in at least one of 256 seeded posterior draws (BoTorch's own
  pruning draws from torch's global generator). With constraints, the hypervolume is
  of feasible outcomes only (each draw's infeasible baseline points are left out of
  its Pareto front, a candidate's improvement is weighted by its smoothed
  feasibility).
- One objective with constraints: ``qLogExpectedImprovement`` with the constraints
  (its improvement weighted by the smoothed probability that the candidate is
  feasible) and ``best_f`` the best *feasible* observation; for a noisy study
  ``qLogNoisyExpectedImprovement`` with the constraints (the incumbent is the best
  feasible point of each posterior draw at the observed points). While no observed
  point is feasible, ``qLogProbabilityOfFeasibility``: the first goal is a feasible
  design.

Reference point (several objectives): ``ProposalRequest.ref_point`` when given;
otherwise inferred at every ask as the nadir of the feasible observations (the worst
observed value of each objective among them) minus 10% of their range in that
objective (BoTorch's ``infer_reference_point``, scale 0.1, applied to the feasible
observations; a single observation: 10% of its magnitude; all observations while
none is feasible). Not Ax's rule, which applies the same formula to the observed
Pareto front only: its box ends just past the front's current extremes, so no
candidate beyond them counts as an improvement and the front is never extended. On
ZDT1 (d = 4, seed 0, bench/multiobjective.py) qei with Ax's rule kept to
f1 in [0, 0.3] and had a hypervolume of 115.68 against (11, 11) after 40
evaluations, where Optuna's GPSampler (whose reference point is 1.1 times the worst
observed value) had 120.50; with the observations' nadir qei had 120.52 after 11.
Every candidate's info records the point (here oriented to be maximised, as the
request is; the service stores it in each objective's own direction), with
``ref_point_source`` (``given`` or ``inferred``).

Failed and infeasible trials (the policy the docs state):

- A *failed* trial (its evaluation crashed: no objectives, no slacks) is left out of
  every model, as with one objective: a crash says nothing about the objectives or
  the constraints. Its design enters the acquisition as a pending point, so the
  exact design is not proposed again and its neighbourhood is discounted as a
  running trial's is. It is not counted as infeasible: a study whose crashes
  correlate with a region should say so with a constraint the evaluation reports.
- An *infeasible* trial (it ran, told its objectives, and broke a constraint:
  some slack > 0) is an observation like any other: every objective GP and every
  constraint GP learns from it, so the constraint models learn where the boundary
  is and the objective models the shape of the response across it. It never counts
  toward the observed Pareto front, the hypervolume baseline or the inferred
  reference point (unless no trial is feasible yet, for the reference point only),
  nor as the incumbent ``best_f`` of one objective.
- Trials with a non-finite objective or slack are dropped (counted in
  ``n_dropped``), as non-finite values are with one objective.

Each model candidate's info adds ``acquisition`` (the name above), ``n_objectives``,
``n_constraints``, ``n_feasible`` (observed feasible trials), for several objectives
``ref_point``, ``ref_point_source``, ``n_pareto`` (the observed feasible front's size),
``lengthscale_prior`` (``unit``: the GPs' spec length scales have
``gpmodel.UNIT_LENGTHSCALE_PRIOR``) and, for qLogNEHVI, ``n_baseline``; and the fit
of each outcome's GP (``fits``).

The Monte Carlo acquisitions (``acquisition: mc``) use ``options["mc_samples"]``
draws (default 128, quasi-random and seeded from ``(seed, n_issued, step)``) and take
turns on qei's Monte Carlo lock as qei's ``mc`` acquisitions do; the analytic ones
set nothing process-wide and run side by side.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from adservice.proposers.base import ProposalRequest, model_inputs
from adservice.proposers.greedy import DEFAULT_RAW_SAMPLES, Greedy, Step
from adservice.proposers.qei_shared import (
    EHVI_CHUNK,
    MC_LOCK,
    MO_RAW_SAMPLES,
    MO_SCREEN_DRAWS,
    PROPOSER_DEVICE,
    QEIOptions,
    limit_threads,
)
from adservice.proposers.simple import derived_seed

BASELINE_DRAWS = 256
"""Posterior draws that decide which observed points stay in qLogNEHVI's baseline."""
FRONT_STARTS = 12
"""Local searches started at the observed front (``front_starts``), at most."""
ETA = 0.05
"""Each constraint's smoothing temperature, in standard deviations of its observed
slacks (the sigmoid that weights a candidate by its feasibility)."""


def _no_kernel_compilation() -> None:
    """BoTorch's LogEHVI compiles a fused C++ kernel with the system's compiler the first
    time it is used in a process (minutes, inside an ask) unless a prebuilt
    ``logei_fused_ext`` module is importable: use a prebuilt one, never compile."""
    from botorch.acquisition.multi_objective import logei

    if getattr(logei, "_load_attempted", True):
        return
    try:
        import logei_fused_ext

        logei._C = logei_fused_ext
    except ImportError:
        pass
    logei._load_attempted = True


def observed_front(objectives: np.ndarray, feasible: np.ndarray) -> np.ndarray:
    """Indices of the feasible rows of ``objectives`` (n x m, maximised) that no other
    feasible row dominates (equal rows: the first only)."""
    from botorch.utils.multi_objective.pareto import is_non_dominated

    rows = np.flatnonzero(feasible)
    if len(rows) == 0:
        return rows
    mask = is_non_dominated(torch.as_tensor(objectives[rows], dtype=torch.float64))
    return rows[mask.numpy()]


def reference_point(
    objectives: np.ndarray, feasible: np.ndarray, given: np.ndarray | None
) -> tuple[np.ndarray, str]:
    """The hypervolume reference point (see the module docstring) and its source."""
    from botorch.utils.multi_objective.hypervolume import infer_reference_point

    if given is not None:
        return np.asarray(given, dtype=np.float64).reshape(-1), "given"
    rows = objectives[feasible] if feasible.any() else objectives
    ref = infer_reference_point(torch.as_tensor(rows, dtype=torch.float64))
    return ref.numpy().astype(np.float64), "inferred"


def front_starts(Z: np.ndarray, objectives: np.ndarray, front: np.ndarray) -> np.ndarray:
    """Where the local searches of qLogNEHVI start besides the raw samples: up to
    ``FRONT_STARTS`` of the observed front's designs and the midpoints (model inputs)
    of front designs next to each other in the first objective. The hypervolume
    improves most in the front's gaps, which often lie on a face of the box that
    random raw samples never come near (ZDT's front has every coordinate but the
    first at 0): started from the raw samples alone, qei kept probing the corners of
    the box and fell back to Sobol points for 16 of 40 evaluations on ZDT2."""
    order = front[np.argsort(objectives[front, 0], kind="stable")]
    points = Z[order]
    middles = (points[:-1] + points[1:]) / 2.0
    starts = np.concatenate([middles, points])
    if len(starts) <= FRONT_STARTS:
        return starts
    pick = np.linspace(0, len(starts) - 1, FRONT_STARTS).round().astype(np.int64)
    return starts[pick]


class AnalyticLogEHVI:
    """Analytic LogEHVI for the greedy steps of one ask of several objectives (the
    default ``acquisition: analytic``): the log of the expected hypervolume improvement
    of one candidate over the current front, computed exactly rather than by Monte
    Carlo. The objectives' GPs are independent, so a candidate's improvement in a
    hyper-rectangle cell of the non-dominated region (BoTorch's
    ``FastNondominatedPartitioning`` of the front against the reference point) has
    the expectation prod_j E[clamp(min(Y_j, u_j) - l_j, 0)], each factor a difference
    of two expected improvements, sigma_j (h(z_l) - h(z_u)) with h(z) = phi(z) + z Phi(z);
    the sum over cells is taken in log space (``_log_ei_helper``, ``log1mexp``,
    ``logsumexp``), so it keeps a gradient far from the front as LogEI does. The
    front is the feasible observations' (for a noisy study the posterior means at
    them); with constraints, a candidate's LogEHVI adds the log probability that every
    constraint's GP is at or below 0 there, and while nothing is feasible it is that
    log probability alone. Pending points are Kriging believers of every GP (as
    ``posterior.AnalyticLogEI``): their believed objectives join the front when their
    believed slacks are all <= 0, so a candidate gains nothing for duplicating one."""

    def __init__(
        self,
        models: list[Any],
        constraint_models: list[Any],
        train_Z: torch.Tensor,
        objectives: np.ndarray,
        feasible: np.ndarray,
        noisy: bool,
        ref_point: np.ndarray,
    ) -> None:
        from adservice.proposers.posterior import Posterior

        self.objectives = [Posterior(model) for model in models]
        self.constraints = [Posterior(model) for model in constraint_models]
        tkw: dict[str, Any] = {"dtype": train_Z.dtype, "device": train_Z.device}
        self.ref_point = torch.as_tensor(ref_point, **tkw)
        self.any_feasible = bool(feasible.any())
        rows = torch.as_tensor(np.flatnonzero(feasible), device=train_Z.device)
        with torch.no_grad():
            if noisy:
                means = [p.mean_sigma(train_Z[rows])[0] for p in self.objectives]
                self.front = torch.stack(means, dim=-1)
            else:
                self.front = torch.as_tensor(objectives, **tkw)[rows]

    def step(self, pending: torch.Tensor | None) -> tuple[Callable, str]:
        """The acquisition given these pending points, and its name."""
        from botorch.utils.multi_objective.box_decompositions.non_dominated import (
            FastNondominatedPartitioning,
        )

        objectives, constraints, front = self.objectives, self.constraints, self.front
        any_feasible = self.any_feasible
        if pending is not None:
            objectives = [p.believing(pending) for p in objectives]
            constraints = [p.believing(pending) for p in constraints]
            believed = torch.stack([p.beliefs for p in objectives], dim=-1)
            if constraints:
                keep = torch.stack([p.beliefs <= 0 for p in constraints]).all(dim=0)
                believed = believed[keep]
            front = torch.cat([front, believed])
            any_feasible = any_feasible or len(believed) > 0
        name = "LogEHVI" if any_feasible or not constraints else "LogPoF"
        name += "" if pending is None else "-believer"
        cells = None
        if name.startswith("LogEHVI"):
            partitioning = FastNondominatedPartitioning(ref_point=self.ref_point, Y=front)
            cells = partitioning.get_hypercell_bounds()  # lower, upper: cells x m
        return _LogEHVI(objectives, constraints, cells), name


class _LogEHVI:
    """One step's acquisition of ``AnalyticLogEHVI``: b x 1 x D -> b."""

    def __init__(self, objectives: list[Any], constraints: list[Any], cells: Any) -> None:
        self.objectives, self.constraints = objectives, constraints
        if cells is not None:
            lower, upper = cells[0], cells[1]
            self.lower = lower
            self.upper_finite = torch.isfinite(upper)
            # a stand-in where the cell is unbounded, its term masked (finite gradients)
            self.upper = torch.where(self.upper_finite, upper, lower + 1.0)
        self.cells = cells

    def __call__(self, Z: torch.Tensor) -> torch.Tensor:
        X = Z.squeeze(-2)
        value = torch.zeros(X.shape[:-1], dtype=X.dtype, device=X.device)
        for constraint in self.constraints:
            mean, sigma = constraint.mean_sigma(X)
            value = value + torch.special.log_ndtr(-mean / sigma)
        if self.cells is None:
            return value
        per = max(1, EHVI_CHUNK // self.lower.numel())
        parts = [self._log_ehvi(X[start : start + per]) for start in range(0, len(X), per)]
        return value + torch.cat(parts)

    def _log_ehvi(self, X: torch.Tensor) -> torch.Tensor:
        from botorch.acquisition.analytic import _log_ei_helper
        from botorch.utils.safe_math import log1mexp

        stats = [p.mean_sigma(X) for p in self.objectives]
        mean = torch.stack([s[0] for s in stats], dim=-1).unsqueeze(-2)  # b x 1 x m
        sigma = torch.stack([s[1] for s in stats], dim=-1).unsqueeze(-2)
        log_h_lower = _log_ei_helper((mean - self.lower) / sigma)  # b x cells x m
        log_h_upper = torch.where(
            self.upper_finite,
            _log_ei_helper((mean - self.upper) / sigma),
            torch.full_like(log_h_lower, -torch.inf),
        )
        # log(h(z_l) - h(z_u)) = log h(z_l) + log(1 - h(z_u) / h(z_l)); h(z_u) < h(z_l)
        gap = (log_h_upper - log_h_lower).clamp_max(-1e-300)
        log_terms = sigma.log() + log_h_lower + log1mexp(gap)
        return torch.logsumexp(log_terms.sum(dim=-1), dim=-1)


def _slack(index: int) -> Callable[[torch.Tensor], torch.Tensor]:
    def constraint(samples: torch.Tensor) -> torch.Tensor:
        return samples[..., index]

    return constraint


def _first_objective(samples: torch.Tensor, X: torch.Tensor | None = None) -> torch.Tensor:
    return samples[..., 0]


def _pruned_baseline(
    model: Any,
    train_Z: torch.Tensor,
    m: int,
    constraints: list[Callable[[torch.Tensor], torch.Tensor]] | None,
    seed: int,
) -> torch.Tensor:
    """The observed points that are feasible and Pareto-optimal in at least one of
    ``BASELINE_DRAWS`` seeded joint posterior draws (all of them if that is none)."""
    from botorch.sampling.normal import SobolQMCNormalSampler
    from botorch.utils.multi_objective.pareto import is_non_dominated

    sampler = SobolQMCNormalSampler(sample_shape=torch.Size([BASELINE_DRAWS]), seed=seed)
    with torch.no_grad():
        samples = sampler(model.posterior(train_Z))  # draws x n x outcomes
        objectives = samples[..., :m]
        if constraints:
            feasible = torch.stack([c(samples) <= 0 for c in constraints]).all(dim=0)
            objectives = torch.where(
                feasible.unsqueeze(-1), objectives, torch.full_like(objectives, -torch.inf)
            )
        keep = is_non_dominated(objectives, deduplicate=False).any(dim=0)
        if constraints:
            keep &= feasible.any(dim=0)
    return train_Z[keep] if bool(keep.any()) else train_Z


def optimise_outcomes(
    request: ProposalRequest,
    bounds: np.ndarray,
    X: np.ndarray,
    objectives: np.ndarray,
    slacks: np.ndarray,
    X_pending: np.ndarray,
    q: int,
    options: QEIOptions,
    deadline: float | None,
) -> tuple[np.ndarray, dict[str, Any]]:
    """Up to q candidates (fewer when the time budget ran out) and what to record, as
    qei's ``_optimise``: ``objectives`` (n x m, m >= 1, maximised) and ``slacks``
    (n x c, c >= 0, <= 0 satisfied) of the finite observations ``X``."""
    from botorch.acquisition.logei import (
        qLogExpectedImprovement,
        qLogNoisyExpectedImprovement,
        qLogProbabilityOfFeasibility,
    )
    from botorch.acquisition.multi_objective.logei import (
        qLogNoisyExpectedHypervolumeImprovement,
    )
    from botorch.acquisition.multi_objective.objective import IdentityMCMultiOutputObjective
    from botorch.acquisition.objective import GenericMCObjective
    from botorch.models.model_list_gp_regression import ModelListGP
    from botorch.sampling.normal import SobolQMCNormalSampler

    from adservice.proposers.gpfit import fit_outcome
    from adservice.proposers.posterior import AnalyticConstrainedLogEI

    limit_threads(torch)
    _no_kernel_compilation()
    device = torch.device(options.device or PROPOSER_DEVICE)
    tkw: dict[str, Any] = {"dtype": torch.float64, "device": device}
    search = request.structure
    seed = derived_seed(request.seed, request.n_issued)
    m, c = objectives.shape[1], slacks.shape[1]

    Z = model_inputs(X, bounds, search)
    train_Z = torch.as_tensor(Z, **tkw)
    started = time.perf_counter()
    models, fits = [], []
    outcomes = [("" if m == 1 else f"objective {j}", objectives[:, j]) for j in range(m)]
    outcomes += [(f"constraint {j}", slacks[:, j]) for j in range(c)]
    for label, column in outcomes:
        model_j, source = fit_outcome(
            request, options, bounds, X, np.ascontiguousarray(column), tkw, deadline, label
        )
        models.append(model_j)
        fits.append(source)
    model: Any = ModelListGP(*models) if len(models) > 1 else models[0]
    model.eval()
    fit_seconds = time.perf_counter() - started

    feasible = np.all(slacks <= 0, axis=1) if c else np.ones(len(X), dtype=bool)
    analytic: AnalyticConstrainedLogEI | AnalyticLogEHVI | None = None
    n_feasible = int(feasible.sum())
    constraints = [_slack(m + j) for j in range(c)] or None
    # the constraints' smoothing temperature in each slack's own units (BoTorch's is
    # absolute: 1e-3 made an ask with a slack of unit scale take 160 local-search steps)
    eta = torch.as_tensor(ETA * np.maximum(slacks.std(axis=0), 1e-6) if c else np.ones(1), **tkw)
    baseline = train_Z
    extra: dict[str, Any] = {
        "n_objectives": m,
        "n_constraints": c,
        "n_feasible": n_feasible,
    }
    if m >= 2:
        ref, ref_source = reference_point(objectives, feasible, request.ref_point)
        front = observed_front(objectives, feasible)
        extra.update(
            ref_point=[float(v) for v in ref],
            ref_point_source=ref_source,
            n_pareto=len(front),
            lengthscale_prior="unit",  # gpmodel.UNIT_LENGTHSCALE_PRIOR
        )
        incumbents = front_starts(Z, objectives, front) if len(front) else Z[:1]
        if options.acquisition == "analytic":
            analytic = AnalyticLogEHVI(
                models[:m], models[m:], train_Z, objectives, feasible, request.noisy, ref
            )
            acquisition = "LogEHVI" if n_feasible or not c else "LogPoF"
        else:
            acquisition = "qLogNEHVI"
    else:
        best = np.where(feasible, objectives[:, 0], -np.inf)
        incumbents = Z[np.argsort(-best, kind="stable")]
        if n_feasible:
            extra["best_feasible"] = float(best.max())
        if options.acquisition == "analytic":
            analytic = AnalyticConstrainedLogEI(
                models[0], models[1:], train_Z, objectives[:, 0], feasible, request.noisy
            )
            acquisition = "LogCEI" if n_feasible else "LogPoF"
        elif n_feasible == 0:
            acquisition = "qLogPoF"
        else:
            acquisition = "qLogNEI" if request.noisy else "qLogEI"

    default_raw = DEFAULT_RAW_SAMPLES if analytic is not None else MO_RAW_SAMPLES
    greedy = Greedy.of(
        request,
        options,
        bounds,
        Z,
        X_pending,
        incumbents,
        tkw,
        deadline,
        default_raw,
        n_incumbents=len(incumbents) if m >= 2 else 1,
    )
    mc_samples = options.mc_samples or 128
    started = time.perf_counter()

    def make_acquisition(draws: int, step_seed: int, pending_t: torch.Tensor | None) -> Any:
        """The acquisition of this ask with ``draws`` quasi-random posterior draws."""
        sampler = SobolQMCNormalSampler(sample_shape=torch.Size([draws]), seed=step_seed)
        if acquisition == "qLogNEHVI":
            return qLogNoisyExpectedHypervolumeImprovement(
                model=model,
                ref_point=torch.as_tensor(ref, **tkw),
                X_baseline=baseline,
                sampler=sampler,
                objective=IdentityMCMultiOutputObjective(outcomes=list(range(m))) if c else None,
                constraints=constraints,
                eta=eta,
                X_pending=pending_t,
                prune_baseline=False,
            )
        elif acquisition == "qLogPoF":
            assert constraints is not None
            return qLogProbabilityOfFeasibility(
                model=model,
                constraints=constraints,
                eta=eta,
                sampler=sampler,
                X_pending=pending_t,
            )
        elif acquisition == "qLogNEI":
            return qLogNoisyExpectedImprovement(
                model=model,
                X_baseline=baseline,
                sampler=sampler,
                objective=GenericMCObjective(_first_objective),
                constraints=constraints,
                eta=eta,
                X_pending=pending_t,
                prune_baseline=False,
            )
        else:
            return qLogExpectedImprovement(
                model=model,
                best_f=extra["best_feasible"],
                sampler=sampler,
                objective=GenericMCObjective(_first_objective),
                constraints=constraints,
                eta=eta,
                X_pending=pending_t,
            )

    def acquisition_at(step_seed: int, pending_t: torch.Tensor | None) -> Step:
        if analytic is not None:
            return Step(*analytic.step(pending_t))
        screen = None
        if mc_samples > MO_SCREEN_DRAWS:
            screen = make_acquisition(MO_SCREEN_DRAWS, step_seed, pending_t)
        return Step(make_acquisition(mc_samples, step_seed, pending_t), acquisition, screen)

    # the Monte Carlo acquisitions take turns (see qei); the analytic one sets nothing
    with MC_LOCK if analytic is None else contextlib.nullcontext():
        if acquisition == "qLogNEHVI":
            baseline = _pruned_baseline(model, train_Z, m, constraints, derived_seed(seed, q))
            extra["n_baseline"] = len(baseline)
        found = greedy.run(q, seed, acquisition_at)
    extra.update(
        acquisition=acquisition,
        fit=fits[0] if len(set(fits)) == 1 else "mixed",
        fits=fits,
        fit_seconds=round(fit_seconds, 4),
        acq_seconds=round(time.perf_counter() - started, 4),
    )
    if analytic is None:
        extra["mc_samples"] = mc_samples
    return greedy.rows(found, request, bounds, models[0], extra)
