"""Batch log expected improvement on a Gaussian process: the default proposer.

``propose(request)`` returns ``request.count`` candidates in the search box, each with
an info dict saying how it was chosen (``method``: ``sobol``, ``model`` or
``sobol-fallback`` with its ``reason``). The method and why each choice was made:
docs/method.md ("The loop", "The mixed encoding", "The model's choices").

What a caller can rely on:

- **Start.** The first ``n_initial`` candidates of a study are points of its seeded,
  scrambled Sobol sequence (``initial``); a design space's start covers its structures,
  one per structure up to ``initial.COVERED_CHOICES``, as a typed box's categorical
  choices are covered.
- **Looks at other trees** (``options["second_looks"]``). With ``thompson`` (the
  default), every second model candidate after the start of a design space of at most
  ``initial.COVERED_CHOICES`` structures is a look turn (``initial.thompson_turn``):
  one joint posterior draw over each tree's designs (``looks.drawn_tree``) picks a
  tree, and unless it is the incumbent's or has more than ``initial.LOOK_DESIGNS``
  designs (observed, failed or pending), the candidate is a random design of it
  (``method: thompson``, ``second_look: true``). With ``judged`` or ``always``, every
  second model candidate is a look turn while any structure has exactly one design
  (``initial.second_look``): ``judged`` gives each such structure its chance of beating
  the incumbent (``looks.tree_chances``) and maximises the acquisition over those with
  a chance of at least ``initial.LOOK_CHANCE`` alone (with none, a free choice), a
  turn's info saying ``tree_chances``; ``always`` looks among every such structure.
  ``off`` never looks. Several objectives or outcome constraints have no single
  incumbent: ``thompson`` and ``judged`` look never.
- **Model.** After the start, a BoTorch ``SingleTaskGP`` on ``base.model_inputs``
  (structure index and normalised specs, or a box scaled to the unit box), outcomes
  standardised, hyperparameters by maximum a posteriori (``likelihood.fit_map``), the
  covariance ``gpmodel.design_kernel``. Several objectives or outcome constraints
  (``request.objectives``, ``slacks``): one GP per outcome and LogEHVI or constrained
  LogEI (``multiobjective``).
- **Acquisition.** Analytic LogEI (``options["acquisition"] = "analytic"``, the default)
  with pending points as Kriging believers, or BoTorch's Monte Carlo qLogEI / qLogNEI
  (``"mc"``), maximised by ``acquisition.maximise`` with the structure, ints, steps and
  choices held discrete. A batch is chosen greedily: each candidate joins the pending
  points of the next.
- **Pending and failed trials** enter as pending points (failed ones are excluded from
  the GP), so a design that failed or is running is not proposed again.
- **Every candidate is snapped** (``adclient.boxspace``) before it is compared; a
  noise-free study never gets a candidate equal to an observed or pending point while
  another remains.
- **Fallbacks.** Fewer than two distinct usable points, constant observations, or a
  numerical failure of the fit or the search (``model_errors``; any other exception is
  a bug and fails the ask) give the study's Sobol point at ``n_issued + i`` with
  ``method: sobol-fallback`` and the reason; one that a budget or a failed model forced
  also says ``degraded: true`` (counted on the study, shown on the dashboard, by
  ``adclient status`` and on /metrics).
- **Budgets.** Past ``request.seconds`` the fit and the search stop at their best so
  far and the rest of the batch are fallbacks (``budget: time``).
  ``memory.memory_need`` estimates an ask's peak memory; the service refuses an ask
  whose count or options exceed the budget of the device it runs on
  (``memory.device_budget``: ``request.memory_bytes`` on cpu, on cuda at least a share
  of the GPU's memory); past ``max_train`` observations (by default the most that
  budget holds, at most ``subset.CPU_TRAIN`` on cpu) the model is a GP of a subset
  (``subset``), or past ``trust_region.TRUST_FROM`` observations of a continuous box
  with one outcome a trust region (``trust_region``); the ask's info gives ``model``
  (``exact``, ``trust-region`` or ``subset``) and ``n_train`` of ``n_observed``.
- **Determinism.** Every random stream is seeded from ``(seed, n_issued)``; nothing
  draws from torch's global generator. An identical request reuses the exact fit and
  gives bit-identical candidates; the next ask of a study warm-starts its fit from the
  previous optimum (``options["warm_start"] = False`` turns that off, for candidates
  independent of the process's history).
- **Concurrency.** Asks of different studies run side by side; only ``mc`` acquisitions
  take turns on one lock (BoTorch's Monte Carlo posterior sets gpytorch's
  process-wide settings). Torch's intra-op pool is one thread (``AD_TORCH_THREADS``).
- **Device.** The server's ``AD_PROPOSER_DEVICE``, or ``options["device"]`` for one
  study; float64 throughout.

``QEIOptions`` lists every option. Importing this module does not import torch (the
service checks a new study's options with it); ``propose`` does.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from adservice.proposers.base import (
    DEGRADED,
    MAX_FAILED_AS_PENDING,
    Proposal,
    ProposalRequest,
    ProposerOptions,
    model_inputs,
    search_vectors,
)
from adservice.proposers.greedy import Greedy, Step
from adservice.proposers.initial import initial_count, initial_points
from adservice.proposers.memory import MemoryNeed, device_budget, memory_need
from adservice.proposers.qei_shared import (
    GPU_MEMORY_SHARE,
    MC_LOCK,
    PROPOSER_DEVICE,
    QEIOptions,
    limit_threads,
)
from adservice.proposers.simple import derived_seed, scale_to_bounds, sobol_points
from adservice.proposers.subset import CPU_TRAIN, MAX_TRAIN, train_size, training_subset
from adservice.proposers.trust_region import LOCAL_TRAIN, TRUST_FROM, applies, local_training

if TYPE_CHECKING:
    import torch

_DISTINCT_TOL = 1e-9
"""Two vectors closer than this (max-norm, unit box) are the same point."""


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
    keys = np.ascontiguousarray(np.round(unit / _DISTINCT_TOL).astype(np.int64))
    # one bytes key per row: np.unique(axis=0) sorts rows column by column, 10x slower
    return len(np.unique(keys.view(np.dtype((np.void, keys.itemsize * keys.shape[1])))))


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
            n_pending=n_pending + min(n_failed, MAX_FAILED_AS_PENDING),
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
        pending.append(failed[-MAX_FAILED_AS_PENDING:])
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
        device = options.device or PROPOSER_DEVICE
        budget = device_budget(request.memory_bytes, device, GPU_MEMORY_SHARE)
        limit = options.max_train or train_size(
            lambda n: need(n).bytes, budget, MAX_TRAIN if device == "cuda" else CPU_TRAIN
        )
        mode = options.large_history or ("trust-region" if n_observed > TRUST_FROM else "subset")
        local = (
            n_observed > limit
            and mode == "trust-region"
            and applies(structure=request.structure, box=request.box, n_outcomes=outcomes.shape[1])
        )
        if local:
            kept = local_training(observed_Z, y, size=options.max_train or min(limit, LOCAL_TRAIN))
        else:
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
        history = (X, y) if kept is not None and not local else None
        if kept is not None:
            X, y, outcomes = X[kept], y[kept], outcomes[kept]

        import botorch  # noqa: F401  (an import error is a broken install, not a fallback)

        if budget is not None and need(len(y)).bytes > budget:
            return self._fallback(
                request,
                bounds,
                first,
                q,
                f"memory budget: {need(len(y)).describe()}, over the budget of "
                f"{budget / 2**20:.0f} MB per ask",
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
                rows, extra = self._optimise(
                    request,
                    bounds,
                    X,
                    y,
                    X_pending,
                    q,
                    options,
                    deadline,
                    local_of=n_observed if local else None,
                    history=history,
                    observed_Z=observed_Z if kept is not None else None,
                )
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
        extra["model"] = "exact" if kept is None else "trust-region" if local else "subset"
        if kept is not None:
            extra["n_observed"] = n_observed
            extra["train_subset"] = (
                "the best, and others near the best (trust_region.py)"
                if local
                else "best, nearest the best, random (subset.py)"
            )
        from adservice.proposers.acquisition import TAKEN_TOL, nearest_distance

        methods = extra.pop("methods")
        looks = extra.pop("second_looks", [])
        chances = extra.pop("tree_chances", [])
        infos: list[dict[str, Any]] = []
        rows_Z = model_inputs(rows, bounds, request.structure)
        taken = [observed_Z, model_inputs(X_pending, bounds, request.structure)]
        taken = taken if not request.noisy else []
        sobol_rows, sobol_info = self._fallback(request, bounds, first, q, "duplicate candidate")
        for i in range(len(rows)):
            stack = np.concatenate([*taken, rows_Z[:i]], axis=0)
            if nearest_distance(stack, rows_Z[i]) < TAKEN_TOL:
                rows[i] = sobol_rows[i]
                rows_Z[i] = model_inputs(sobol_rows[i], bounds, request.structure)[0]
                infos.append({**sobol_info[i], **extra, "method": "sobol-fallback"})
            else:
                look = {"second_look": True} if i < len(looks) and looks[i] else {}
                if i < len(chances) and chances[i] is not None:
                    look["tree_chances"] = chances[i]
                infos.append({"proposer": self.name, **extra, "method": methods[i], **look})
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
        local_of: int | None = None,
        history: tuple[np.ndarray, np.ndarray] | None = None,
        observed_Z: np.ndarray | None = None,
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Up to q candidates (fewer when the time budget ran out) and what to record;
        ``local_of``: ``X`` are the best of that many observations, and the search stays
        in the trust region around the best (``trust_region``); ``history``: the whole
        history ``X`` and ``y`` are a training subset of (``gpfit.fit_outcome``);
        ``observed_Z``: every observation's model inputs where ``X`` is a subset, so the
        search answers none of them (a point outside the subset is a duplicate too)."""
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
        model, fit_source = fit_outcome(
            request, options, bounds, X, y, tkw, deadline, history=history
        )
        fit_seconds = time.perf_counter() - started

        mc_samples = options.mc_samples or 128
        greedy = Greedy.of(
            request, options, bounds, Z, X_pending, Z[np.argsort(-y, kind="stable")], tkw, deadline
        )
        if observed_Z is not None and greedy.taken is not None:
            greedy = replace(greedy, taken=np.concatenate([observed_Z, greedy.pending_Z]))
        region: dict[str, Any] = {}
        if local_of is not None:
            from adservice.proposers.trust_region import spec_lengthscales, trust_box

            box = trust_box(
                Z[int(np.argmax(y))], spec_lengthscales(model), n_train=len(y), n_observed=local_of
            )
            greedy, region = replace(greedy, trust=box), box.describe()
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

            found = greedy.run(
                q,
                seed,
                acquisition_at,
                _judge(greedy, model, analytic, y, tkw),
                _draw(greedy, model, analytic, tkw),
            )
        extra: dict[str, Any] = {
            "fit": fit_source,
            "fit_seconds": round(fit_seconds, 4),
            "acq_seconds": round(time.perf_counter() - started, 4),
            **region,
        }
        return greedy.rows(found, request, bounds, model, extra)


def _judge(
    greedy: Greedy, model: Any, analytic: Any, y: np.ndarray, tkw: dict[str, Any]
) -> Callable[[np.ndarray, int], np.ndarray] | None:
    """The tree judgement of a judged second look (``looks.tree_chances``) on this
    ask's fitted model, against the acquisition's incumbent; None where no ask of this
    study looks."""
    if greedy.structure_counts is None or not greedy.judged:
        return None
    from adservice.proposers.looks import tree_chances
    from adservice.proposers.posterior import Posterior

    posterior = analytic.posterior if analytic is not None else Posterior(model)
    incumbent = analytic.incumbent if analytic is not None else float(y.max())

    def judge(trees: np.ndarray, step_seed: int) -> np.ndarray:
        return tree_chances(
            posterior, greedy.domain, trees, greedy.incumbents, incumbent, step_seed, tkw
        )

    return judge


def _draw(
    greedy: Greedy, model: Any, analytic: Any, tkw: dict[str, Any]
) -> Callable[[np.ndarray, int], int] | None:
    """Thompson sampling across trees (``looks.drawn_tree``) on this ask's fitted
    model; None where no ask of this study looks."""
    if greedy.structure_counts is None or not greedy.thompson:
        return None
    from adservice.proposers.looks import drawn_tree
    from adservice.proposers.posterior import Posterior

    posterior = analytic.posterior if analytic is not None else Posterior(model)

    def draw(trees: np.ndarray, step_seed: int) -> int:
        return drawn_tree(posterior, greedy.domain, trees, greedy.incumbents, step_seed, tkw)

    return draw


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
