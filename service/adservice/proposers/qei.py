"""Batch log expected improvement on a Gaussian process: the default proposer.

The method of the preprint ("The loop" in docs/method.md), with the model and acquisition
of docs/method.md, "The mixed encoding": the first ``n_initial`` trials of a study are points of its
seeded scrambled Sobol sequence; after that a BoTorch ``SingleTaskGP`` (outcomes
standardised, hyperparameters fitted by maximum a posteriori marginal likelihood with
``gpmodel.fit_map``)
with the covariance of ``gpmodel.design_kernel`` scores candidates with analytic
LogEI, and ``acquisition.maximise`` finds the best one with the structure held
discrete. A batch of ``count`` is chosen greedily: each candidate joins the pending
points of the next.

The model's input is ``[structure index, specs]`` (``base.model_inputs``): a box's
coordinates scaled to the unit box, a design space's normalised specs with the
slots a structure does not use at the pad value. With several structures (the
``mixed`` representation) the kernel relates them through their places in the fused
geometry; joint axes enter as unit vectors. The preprint's ``fused`` and the
``onehot`` representations are searched as plain boxes.

Decisions worth knowing:

- Acquisition (``options["acquisition"]``): ``analytic`` (default) is LogEI on the
  posterior computed directly (``posterior.Posterior``), with pending points as
  Kriging believers (the model conditioned on its own mean there) and, for a noisy
  study, the best posterior mean at the observed points as the incumbent. ``mc`` is
  BoTorch's Monte Carlo qLogEI (qLogNEI when noisy) with the pending points, also
  greedy; it costs several times more per ask.
- Noise: a noisy study gets BoTorch's default inferred noise (LogNormal prior,
  floor 1e-4 of the standardised variance). A noise-free study still
  infers its noise, but with no prior and a floor of 1e-6: with the 1e-4 floor
  the GP cannot resolve the last per-cent of a function with a wide range (on
  Branin qei then missed the 1% target in 2 of 3 runs; with the low floor it
  reached it in 23-28 evaluations). ``options["noise"]`` may choose ``"inferred"``,
  ``"floor"`` or ``"fixed"`` (1e-6, as Optuna's deterministic GP);
  ``options["kernel"]`` ``"matern"`` (Matern-5/2, the default: on Hartmann6 it
  reached the 1% target in 6 of 10 seeds where the RBF reached it in 4 of 9) or
  ``"rbf"``, both with BoTorch's dimension-scaled length-scale prior.

- The start covers the structures (issue 26): a design space's initial Sobol points
  are dealt one per structure, up to ``initial.COVERED_CHOICES`` (``structure_order``:
  farthest-first in the fused geometry from a seeded first one), as a typed box's
  categorical choices are. A GP cannot rank a structure it never saw: from the
  preprint's two-design start the model kept to the first good tree on every objective
  where a wrong tree improves with its specs (bench/RESULTS.md, issue 26).
- Fit and search tolerances: the MAP fit stops at GPSampler's gradient tolerance
  (``gpmodel.FIT_GTOL``), a warm-started fit after ``gpfit.WARM_MAXITER`` iterations,
  a local search of the acquisition at ``acquisition.LOCAL_GTOL``; a history longer than
  ``gpfit.FIT_POINTS`` has its hyperparameters fitted on a subset (``gpfit.fit_subset``)
  and its posterior on every observation.
- Failed trials are *excluded* from the GP (a crashed simulation says nothing
  about the score surface), and enter the acquisition as pending points, so that
  the exact design that failed is not proposed again and its neighbourhood is
  discounted the way a pending point's is. No feasibility classifier.
- Pending (queued/running) trials enter as ``X_pending``; so do the Sobol points
  issued earlier in the same batch.
- Typed box params (``request.box``, see ``adclient.boxspace``): a log scale is in the
  encoding (the model and the acquisition see ln x, linearly), ints and stepped floats
  are ordered specs the acquisition keeps on their grid, categoricals enter the kernel
  as one-hot vectors (``gpmodel``), and ``acquisition.maximise`` alternates a
  continuous step with a discrete neighbour step (BoTorch's mixed-alternating
  scheme). Every candidate, Sobol points included, is snapped before it is compared
  with observed and pending points, and a noise-free study's model candidate is the
  best point found that is neither, while one remains.
- Fallbacks: with fewer than two distinct usable points, constant observations, or a
  fit or acquisition optimisation that fails numerically (``model_errors``; any other
  exception is a bug and fails the ask), the candidate is the study's Sobol point at
  position ``n_issued + i`` and its info dict says ``"method": "sobol-fallback"`` with
  the ``"reason"``; one a budget or a failed model forced says ``"degraded": true``
  (counted on the study, shown by the dashboard, ``adclient status`` and /metrics). A
  model candidate that duplicates another candidate of the batch (or, for noise-free
  studies, an already observed or pending point) is replaced the same way.
- Seeding: the acquisition's quasi-Monte-Carlo samplers (the noisy baseline's
  pruning included) and the raw samples of the restarts have generators of their
  own, seeded from ``(seed, n_issued)``; nothing draws from torch's global generator,
  so concurrent asks cannot disturb each other's random streams.
- Concurrency: asks of different studies run side by side (issue 13: one lock for
  every fit let a 35 s ask hold up every other study). The fit caches have a lock of
  their own held only to read or store an entry; warnings are not filtered with
  ``warnings.catch_warnings`` (it swaps the process's filter list); torch's and the
  BLAS's thread counts are set once per thread and never restored. Only ``mc``
  acquisitions take turns on one lock (their fits do not): BoTorch's Monte Carlo
  posterior sets and restores gpytorch's process-wide settings at every call, and
  side by side they changed each other's candidates (by up to 5e-4).
- Budgets (``ProposalRequest.seconds``, ``memory_bytes``; the server's
  ``AD_ASK_SECONDS``, ``AD_ASK_MEMORY_MB``): past the time budget the fit and the
  acquisition search stop at their best so far, the candidate being searched is
  kept and the rest of the batch are Sobol fallbacks; every model trial of the ask
  says ``"budget": "time"``. ``memory.memory_need`` estimates an ask's peak memory from its
  options and sizes (the service refuses an ask whose count or options exceed the
  memory budget); one that exceeds it through its history alone falls back to Sobol
  points with the reason. Past ``max_train`` observations (by default the most the
  memory budget holds, at most 4096) the model trains on a subset (``subset``), so the
  history alone no longer outgrows the budget.
- Acquisition optimisation: as GPSampler, 2048 Sobol points and 10 local searches
  (L-BFGS-B) per candidate (``options`` may override ``num_restarts``,
  ``raw_samples``, ``maxiter``; with only ``raw_samples`` given, the restarts are at
  most that many); see ``acquisition``. Fitted hyperparameters (``gpfit``) are kept
  in two small in-process LRU caches: by a digest of the exact training data (an
  identical request re-uses the exact fit, so it gives bit-identical candidates),
  and by the study's identity (bounds, layout, seed, n_initial, noise, kernel and its
  first two observations: the next ask of the same study warm-starts its fit from the
  previous optimum, and another study of the same box never does, since a fit
  started from another function's optimum can stop in a worse local optimum). A server that
  restarts loses the caches; its next fit starts cold and converges to the same
  optimum up to the optimiser's tolerance, so candidates agree closely but are
  not guaranteed bit-identical to those of the server that warm-started. Set
  ``options["warm_start"] = False`` for strict restart-independence.
- The device is the server's ``ADPROPOSER_DEVICE`` (``cpu`` unless set to ``cuda``);
  ``options["device"]`` overrides it for one study. Everything runs in float64.
- Threads: torch's intra-op pool is set to one thread (``AD_TORCH_THREADS``
  overrides). These are small matrices; on a shared two-core machine two torch
  threads competing with other processes made asks 5 to 20 times slower, and the
  server already runs each ask in its own thread.
- Several objectives (``ProposalRequest.objectives``) and outcome constraints
  (``slacks``), issue 17: after the same Sobol start, one GP per outcome and LogEHVI
  (several objectives: analytic by default, Monte Carlo qLogNEHVI with ``mc``) or a
  constrained LogEI (one), with the same kernels, domains, pending points, fallbacks
  and budgets; the reference point, and how failed and infeasible trials are
  treated, are in ``multiobjective``.
- ``QEIOptions`` lists every option. Importing this module does not import torch
  (the service checks a new study's options with it); ``propose`` does.
"""

from __future__ import annotations

import contextlib
import time
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from adservice.proposers.base import (
    DEGRADED,
    Proposal,
    ProposalRequest,
    ProposerOptions,
    model_inputs,
    search_vectors,
)
from adservice.proposers.greedy import Greedy, Step
from adservice.proposers.initial import initial_count, initial_points
from adservice.proposers.memory import MemoryNeed, memory_need
from adservice.proposers.qei_shared import (
    MC_LOCK,
    PROPOSER_DEVICE,
    QEIOptions,
    limit_threads,
)
from adservice.proposers.simple import derived_seed, scale_to_bounds, sobol_points
from adservice.proposers.subset import MAX_TRAIN, train_size, training_subset

if TYPE_CHECKING:
    import torch

_DISTINCT_TOL = 1e-9
"""Two vectors closer than this (max-norm, unit box) are the same point."""
_DUPLICATE_CANDIDATE_TOL = 1e-6
_MAX_FAILED_AS_PENDING = 32


def model_errors() -> tuple[type[BaseException], ...]:
    """The exceptions a fit or an acquisition search raises on numbers it cannot handle
    (a covariance not positive definite, NaN, an overflow, out of memory: torch's and
    gpytorch's are RuntimeErrors, BoTorch's its own), which fall back to Sobol points;
    a TypeError, KeyError, AttributeError or AssertionError is a bug and fails the ask."""
    from botorch.exceptions import BotorchError

    return (
        ArithmeticError,
        MemoryError,
        RuntimeError,
        ValueError,
        np.linalg.LinAlgError,
        BotorchError,
    )


def _n_distinct(unit: np.ndarray) -> int:
    if len(unit) == 0:
        return 0
    keys = np.round(unit / _DISTINCT_TOL).astype(np.int64)
    return len(np.unique(keys, axis=0))


class QLogEIProposer:
    """Sobol start, then a GP with batch log expected improvement (noisy variant on request)."""

    name: ClassVar[str] = "qei"
    needs_history: ClassVar[bool] = True
    multi_objective: ClassVar[bool] = True
    constrained: ClassVar[bool] = True
    options_model: ClassVar[type[ProposerOptions]] = QEIOptions

    @staticmethod
    def memory_need(
        options: dict[str, Any],
        *,
        dim: int,
        count: int,
        n_train: int,
        n_pending: int,
        n_failed: int,
        n_objectives: int = 1,
        n_constraints: int = 0,
    ) -> MemoryNeed:
        """``memory_need`` for the service: options as stored, failed trials counted as
        ``propose`` counts them (the latest few, as pending points); a study of several
        objectives or with constraints passes their numbers."""
        return memory_need(
            QEIOptions.model_validate(options),
            dim=dim,
            count=count,
            n_train=n_train,
            n_pending=n_pending + min(n_failed, _MAX_FAILED_AS_PENDING),
            n_objectives=n_objectives,
            n_constraints=n_constraints,
        )

    def propose(self, request: ProposalRequest) -> Proposal:
        deadline = None if request.seconds is None else time.monotonic() + request.seconds
        options = QEIOptions.model_validate(request.options)
        count = request.count
        bounds = np.asarray(request.bounds, dtype=np.float64)
        candidates = np.empty((count, request.dim), dtype=np.float64)
        info: list[dict[str, Any]] = [{} for _ in range(count)]

        n_sobol = min(max(initial_count(request) - request.n_issued, 0), count)
        if n_sobol:
            candidates[:n_sobol] = initial_points(request, bounds, n_sobol)
            for i in range(n_sobol):
                info[i] = {
                    "proposer": self.name,
                    "method": "sobol-initial",
                    "sobol_index": request.n_issued + i,
                }
        if n_sobol == count:
            return Proposal(candidates=_canonical(candidates, bounds, request), info=info)

        q = count - n_sobol
        model_rows, model_info = self._model_batch(
            request, bounds, q, candidates[:n_sobol], options, deadline
        )
        candidates[n_sobol:] = model_rows
        info[n_sobol:] = model_info
        return Proposal(candidates=_canonical(candidates, bounds, request), info=info)

    # -- the model phase -------------------------------------------------------------

    def _fallback(
        self,
        request: ProposalRequest,
        bounds: np.ndarray,
        first: int,
        q: int,
        reason: str,
        *,
        degraded: bool = False,
    ) -> tuple[np.ndarray, list[dict[str, Any]]]:
        """Sobol points in place of model candidates; ``degraded`` when the model could
        have proposed but a budget or a failed fit stopped it (``DEGRADED``)."""
        start = request.n_issued + first
        unit = sobol_points(request.dim, request.seed, start, q)
        info = [
            {
                "proposer": self.name,
                "method": "sobol-fallback",
                "reason": reason,
                "sobol_index": start + i,
                **({DEGRADED: True} if degraded else {}),
            }
            for i in range(q)
        ]
        return _snapped(scale_to_bounds(unit, bounds), request), info

    def _model_batch(
        self,
        request: ProposalRequest,
        bounds: np.ndarray,
        q: int,
        issued_now: np.ndarray,
        options: QEIOptions,
        deadline: float | None,
    ) -> tuple[np.ndarray, list[dict[str, Any]]]:
        first = request.count - q
        X = np.asarray(request.X, dtype=np.float64).reshape(-1, request.dim)
        y = np.asarray(request.y, dtype=np.float64).reshape(-1)
        outcomes = _outcomes(request, y)
        usable = np.all(np.isfinite(outcomes), axis=1) & np.all(np.isfinite(X), axis=1)
        X, y, outcomes = X[usable], y[usable], outcomes[usable]
        n_dropped = int((~usable).sum())
        observed_Z = model_inputs(X, bounds, request.structure)
        n_distinct = _n_distinct(observed_Z)
        if n_distinct < 2:
            return self._fallback(
                request, bounds, first, q, f"fewer than 2 distinct observed points ({n_distinct})"
            )
        y_scale = np.maximum(1.0, np.max(np.abs(outcomes), axis=0))
        if np.all(np.ptp(outcomes, axis=0) <= 1e-12 * y_scale):
            return self._fallback(
                request, bounds, first, q, f"constant observations (all y = {y[0]:.6g})"
            )

        pending = [np.asarray(request.pending, dtype=np.float64).reshape(-1, request.dim)]
        failed = np.asarray(request.failed, dtype=np.float64).reshape(-1, request.dim)
        pending.append(failed[-_MAX_FAILED_AS_PENDING:])
        pending.append(issued_now)
        X_pending = np.concatenate(pending, axis=0)
        X_pending = X_pending[np.all(np.isfinite(X_pending), axis=1)]
        X_pending = np.clip(X_pending, bounds[0], bounds[1])
        n_objectives = 1 if request.objectives is None else request.objectives.shape[1]

        def need(n_train: int) -> MemoryNeed:
            return memory_need(
                options,
                dim=request.dim,
                count=q,
                n_train=n_train,
                n_pending=len(X_pending),
                n_objectives=n_objectives,
                n_constraints=outcomes.shape[1] - n_objectives,
            )

        n_observed = len(y)
        limit = options.max_train or train_size(
            lambda n: need(n).bytes, request.memory_bytes, MAX_TRAIN
        )
        front = None
        if request.objectives is not None and n_observed > limit:
            from adservice.proposers.multiobjective import observed_front

            m = int(request.objectives.shape[1])
            front = observed_front(outcomes[:, :m], np.all(outcomes[:, m:] <= 0, axis=1))
        kept = training_subset(
            observed_Z,
            outcomes[:, 0],
            limit=limit,
            seed=request.seed,
            n_issued=request.n_issued,
            front=front,
        )
        if kept is not None:
            X, y, outcomes = X[kept], y[kept], outcomes[kept]

        import botorch  # noqa: F401  (an import error is a broken install, not a fallback)

        if request.memory_bytes is not None and need(len(y)).bytes > request.memory_bytes:
            return self._fallback(
                request,
                bounds,
                first,
                q,
                f"memory budget: {need(len(y)).describe()}, over the budget of "
                f"{request.memory_bytes / 2**20:.0f} MB per ask",
                degraded=True,
            )

        cpu_started = time.thread_time()
        try:
            if outcomes.shape[1] > 1:
                from adservice.proposers.multiobjective import optimise_outcomes

                m = 1 if request.objectives is None else int(request.objectives.shape[1])
                rows, extra = optimise_outcomes(
                    request,
                    bounds,
                    X,
                    outcomes[:, :m],
                    outcomes[:, m:],
                    X_pending,
                    q,
                    options,
                    deadline,
                )
            else:
                rows, extra = self._optimise(request, bounds, X, y, X_pending, q, options, deadline)
        except model_errors() as error:  # a numerical failure degrades; a bug raises
            reason = f"model failed: {type(error).__name__}: {error}"[:300]
            return self._fallback(request, bounds, first, q, reason, degraded=True)

        extra.update(
            cpu_seconds=round(time.thread_time() - cpu_started, 4),
            n_train=len(y),
            n_distinct=n_distinct,
            n_pending=len(X_pending),
            n_dropped=n_dropped,
        )
        if n_observed > n_distinct:
            extra["duplicate_points"] = n_observed - n_distinct
        if kept is not None:
            extra["n_observed"] = n_observed
            extra["train_subset"] = "best, nearest the best, random (subset.py)"
        methods = extra.pop("methods")
        infos: list[dict[str, Any]] = []
        rows_Z = model_inputs(rows, bounds, request.structure)
        taken = [observed_Z, model_inputs(X_pending, bounds, request.structure)]
        taken = taken if not request.noisy else []
        sobol_rows, sobol_info = self._fallback(request, bounds, first, q, "duplicate candidate")
        for i in range(len(rows)):
            stack = np.concatenate([*taken, rows_Z[:i]], axis=0)
            if _nearest_distance(stack, rows_Z[i]) < _DUPLICATE_CANDIDATE_TOL:
                rows[i] = sobol_rows[i]
                rows_Z[i] = model_inputs(sobol_rows[i], bounds, request.structure)[0]
                infos.append({**sobol_info[i], **extra, "method": "sobol-fallback"})
            else:
                infos.append({"proposer": self.name, **extra, "method": methods[i]})
        if len(rows) < q:
            done = len(rows)
            late_rows, late_info = self._fallback(
                request,
                bounds,
                first + done,
                q - done,
                f"time budget: {request.seconds:g} s spent after {done} of {q} model candidates",
                degraded=True,
            )
            rows = np.concatenate([rows, late_rows])
            infos += [{**info, "budget": "time"} for info in late_info]
        return rows, infos

    def _optimise(
        self,
        request: ProposalRequest,
        bounds: np.ndarray,
        X: np.ndarray,
        y: np.ndarray,
        X_pending: np.ndarray,
        q: int,
        options: QEIOptions,
        deadline: float | None,
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Up to q candidates (fewer when the time budget ran out) and what to record."""
        import torch
        from botorch.acquisition.logei import (
            qLogExpectedImprovement,
            qLogNoisyExpectedImprovement,
        )
        from botorch.acquisition.utils import prune_inferior_points
        from botorch.sampling.normal import SobolQMCNormalSampler

        from adservice.proposers.gpfit import fit_outcome
        from adservice.proposers.posterior import AnalyticLogEI

        limit_threads(torch)
        device = torch.device(options.device or PROPOSER_DEVICE)
        tkw: dict[str, Any] = {"dtype": torch.float64, "device": device}
        search = request.structure
        seed = derived_seed(request.seed, request.n_issued)

        Z = model_inputs(X, bounds, search)
        train_Z = torch.as_tensor(Z, **tkw)
        started = time.perf_counter()
        model, fit_source = fit_outcome(request, options, bounds, X, y, tkw, deadline)
        fit_seconds = time.perf_counter() - started

        mc_samples = options.mc_samples or 128
        greedy = Greedy.of(
            request, options, bounds, Z, X_pending, Z[np.argsort(-y, kind="stable")], tkw, deadline
        )
        started = time.perf_counter()
        analytic = (
            AnalyticLogEI(model, train_Z, y, request.noisy)
            if options.acquisition == "analytic"
            else None
        )
        # gpytorch's settings are class attributes that BoTorch's Monte Carlo posterior
        # sets and restores at every call: those acquisitions take turns (the analytic
        # one sets none)
        with MC_LOCK if analytic is None else contextlib.nullcontext():
            baseline = train_Z
            if analytic is None and request.noisy:
                # BoTorch's own pruning would seed its sampler from torch's global generator
                with torch.no_grad():
                    baseline = prune_inferior_points(
                        model,
                        train_Z,
                        sampler=SobolQMCNormalSampler(
                            sample_shape=torch.Size([2048]), seed=derived_seed(seed, q)
                        ),
                    )

            def acquisition_at(step_seed: int, pending_t: torch.Tensor | None) -> Step:
                if analytic is not None:
                    return Step(*analytic.step(pending_t))
                sampler = SobolQMCNormalSampler(
                    sample_shape=torch.Size([mc_samples]), seed=step_seed
                )
                if request.noisy:
                    noisy = qLogNoisyExpectedImprovement(
                        model=model,
                        X_baseline=baseline,
                        sampler=sampler,
                        X_pending=pending_t,
                        prune_baseline=False,
                    )
                    return Step(noisy, "qLogNEI")
                plain = qLogExpectedImprovement(
                    model=model, best_f=float(y.max()), sampler=sampler, X_pending=pending_t
                )
                return Step(plain, "qLogEI")

            found = greedy.run(q, seed, acquisition_at)
        extra: dict[str, Any] = {
            "fit": fit_source,
            "fit_seconds": round(fit_seconds, 4),
            "acq_seconds": round(time.perf_counter() - started, 4),
        }
        return greedy.rows(found, request, bounds, model, extra)


def _outcomes(request: ProposalRequest, y: np.ndarray) -> np.ndarray:
    """The observations' objectives then slacks, one column each (n x (m + c)); ``y``
    alone for one objective without constraints."""
    columns = [y[:, None]]
    if request.objectives is not None:
        columns = [columns_of(request.objectives, len(y))]
    if request.slacks is not None:
        columns.append(columns_of(request.slacks, len(y)))
    return np.column_stack(columns)


def columns_of(values: np.ndarray, n: int) -> np.ndarray:
    """``objectives`` or ``slacks`` of n trials as an n x k float array (a 1-d array is
    one column)."""
    values = np.asarray(values, dtype=np.float64)
    return values.reshape(n, values.shape[-1] if values.ndim == 2 else 1)


def _snapped(candidates: np.ndarray, request: ProposalRequest) -> np.ndarray:
    """A typed box's points as the params they stand for (``BoxEncoding.snap``)."""
    return candidates if request.box is None else request.box.snap(candidates)


def _canonical(candidates: np.ndarray, bounds: np.ndarray, request: ProposalRequest) -> np.ndarray:
    """Candidates in the box; for a design space, as the designs they stand for: an
    integral structure index and unused slots at the pad (Sobol points included); for
    a typed box, snapped."""
    candidates = _snapped(np.clip(candidates, bounds[0], bounds[1]), request)
    if request.structure is None:
        return candidates
    return search_vectors(
        model_inputs(candidates, bounds, request.structure), bounds, request.structure
    )


def _nearest_distance(points: np.ndarray, point: np.ndarray) -> float:
    """Max-norm distance from ``point`` to the nearest row of ``points`` (inf if none)."""
    if len(points) == 0:
        return float("inf")
    return float(np.min(np.max(np.abs(points - point), axis=1)))
