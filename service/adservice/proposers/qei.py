"""Batch log expected improvement on a Gaussian process: the default proposer.

The method of the preprint (section 1 of DESIGN.md), with the model and acquisition
of DESIGN.md section 2a: the first ``n_initial`` trials of a study are points of its
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
  posterior computed directly (``gpmodel.Posterior``), with pending points as
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

- Failed trials are *excluded* from the GP (a crashed simulation says nothing
  about the score surface), and enter the acquisition as pending points, so that
  the exact design that failed is not proposed again and its neighbourhood is
  discounted the way a pending point's is. No feasibility classifier.
- Pending (queued/running) trials enter as ``X_pending``; so do the Sobol points
  issued earlier in the same batch.
- Fallbacks never raise: with fewer than two distinct usable points, constant
  observations, or a fit or acquisition optimisation that fails, the candidate
  is the study's Sobol point at position ``n_issued + i`` and its info dict says
  ``"method": "sobol-fallback"`` with the ``"reason"``. A model candidate that
  duplicates another candidate of the batch (or, for noise-free studies, an
  already observed or pending point) is replaced the same way.
- Seeding: the acquisition's quasi-Monte-Carlo sampler, the raw samples of the
  restarts and any random re-start of the fit are seeded from
  ``(seed, n_issued)``, under a process-wide lock so concurrent asks cannot
  disturb each other's random streams.
- Acquisition optimisation: as GPSampler, 2048 Sobol points and 10 local searches
  (L-BFGS-B) per candidate (``options`` may override ``num_restarts``,
  ``raw_samples``, ``maxiter``; with only ``raw_samples`` given, the restarts are at
  most that many); see ``acquisition``. Fitted hyperparameters are kept
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
- The GPU is used when ``torch.cuda.is_available()`` (``options["device"]`` may
  force ``"cpu"``); everything runs in float64.
- Threads: torch's intra-op pool is set to one thread (``AD_TORCH_THREADS``
  overrides). These are small matrices; on a shared two-core machine two torch
  threads competing with other processes made asks 5 to 20 times slower, and the
  server already runs each ask in its own thread.
- ``QEIOptions`` lists every option. Importing this module does not import torch
  (the service checks a new study's options with it); ``propose`` does.
"""

from __future__ import annotations

import hashlib
import threading
import time
import warnings
from collections import OrderedDict
from typing import TYPE_CHECKING, Any, ClassVar, Literal

import numpy as np
from pydantic import Field, model_validator

from adservice.proposers.base import (
    Proposal,
    ProposalRequest,
    ProposerOptions,
    SearchStructure,
    model_inputs,
    search_vectors,
)
from adservice.proposers.simple import derived_seed, scale_to_bounds, sobol_points
from adservice.settings import get_settings

if TYPE_CHECKING:
    import torch

_LOCK = threading.Lock()
_CACHE_SIZE = 256
_FITS_BY_DATA: OrderedDict[str, dict[str, torch.Tensor]] = OrderedDict()
_FITS_BY_STUDY: OrderedDict[tuple[Any, ...], dict[str, torch.Tensor]] = OrderedDict()
_DISTINCT_TOL = 1e-9
"""Two vectors closer than this (max-norm, unit box) are the same point."""
_DUPLICATE_CANDIDATE_TOL = 1e-6
_MAX_FAILED_AS_PENDING = 32
_TORCH_THREADS = get_settings().torch_threads


def clear_caches() -> None:
    """Forget every cached fit (tests and benchmarks measure cold starts with it)."""
    with _LOCK:
        _FITS_BY_DATA.clear()
        _FITS_BY_STUDY.clear()


def _lru_put(cache: OrderedDict, key: Any, value: Any) -> None:
    cache[key] = value
    cache.move_to_end(key)
    while len(cache) > _CACHE_SIZE:
        cache.popitem(last=False)


def _lru_get(cache: OrderedDict, key: Any) -> Any:
    value = cache.get(key)
    if value is not None:
        cache.move_to_end(key)
    return value


def _n_distinct(unit: np.ndarray) -> int:
    if len(unit) == 0:
        return 0
    keys = np.round(unit / _DISTINCT_TOL).astype(np.int64)
    return len(np.unique(keys, axis=0))


DEFAULT_RESTARTS = 10
"""Local searches per candidate (GPSampler's n_local_search)."""
DEFAULT_RAW_SAMPLES = 2048
"""Sobol points the starts are chosen from (GPSampler's n_preliminary_samples)."""


class QEIOptions(ProposerOptions):
    """qei's options; see the module docstring for what each choice does."""

    noise: Literal["inferred", "floor", "fixed"] | None = Field(
        default=None, description="Default: inferred for a noisy study, else floor"
    )
    kernel: Literal["rbf", "matern"] = "matern"
    num_restarts: int | None = Field(
        default=None, ge=1, le=128, description="Local searches per candidate. Default: 10"
    )
    raw_samples: int | None = Field(
        default=None,
        ge=1,
        le=16_384,
        description="Sobol points the starts come from. Default: 2048",
    )
    maxiter: int = Field(default=100, ge=1, le=10_000)
    mc_samples: int | None = Field(
        default=None, ge=1, le=4096, description="acquisition: mc only. Default: 128"
    )
    acquisition: Literal["analytic", "mc"] = Field(
        default="analytic",
        description="analytic LogEI with pending points as Kriging believers, or "
        "Monte Carlo qLogEI / qLogNEI with pending points",
    )
    warm_start: bool = True
    device: Literal["cpu", "cuda"] | None = Field(
        default=None, description="Default: cuda when available"
    )

    @model_validator(mode="after")
    def _enough_raw_samples(self) -> QEIOptions:
        if (
            self.num_restarts is not None
            and self.raw_samples is not None
            and self.raw_samples < self.num_restarts
        ):
            raise ValueError(
                f"raw_samples ({self.raw_samples}) must be >= num_restarts "
                f"({self.num_restarts}): each restart starts from one raw sample"
            )
        return self


class QLogEIProposer:
    """Sobol start, then a GP with batch log expected improvement (noisy variant on request)."""

    name: ClassVar[str] = "qei"
    needs_history: ClassVar[bool] = True
    options_model: ClassVar[type[ProposerOptions]] = QEIOptions

    def propose(self, request: ProposalRequest) -> Proposal:
        options = QEIOptions.model_validate(request.options)
        count = request.count
        bounds = np.asarray(request.bounds, dtype=np.float64)
        candidates = np.empty((count, request.dim), dtype=np.float64)
        info: list[dict[str, Any]] = [{} for _ in range(count)]

        n_sobol = min(max(request.n_initial - request.n_issued, 0), count)
        if n_sobol:
            unit = sobol_points(request.dim, request.seed, request.n_issued, n_sobol)
            candidates[:n_sobol] = scale_to_bounds(unit, bounds)
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
            request, bounds, q, candidates[:n_sobol], options
        )
        candidates[n_sobol:] = model_rows
        info[n_sobol:] = model_info
        return Proposal(candidates=_canonical(candidates, bounds, request), info=info)

    # -- the model phase -------------------------------------------------------------

    def _fallback(
        self, request: ProposalRequest, bounds: np.ndarray, first: int, q: int, reason: str
    ) -> tuple[np.ndarray, list[dict[str, Any]]]:
        start = request.n_issued + first
        unit = sobol_points(request.dim, request.seed, start, q)
        info = [
            {
                "proposer": self.name,
                "method": "sobol-fallback",
                "reason": reason,
                "sobol_index": start + i,
            }
            for i in range(q)
        ]
        return scale_to_bounds(unit, bounds), info

    def _model_batch(
        self,
        request: ProposalRequest,
        bounds: np.ndarray,
        q: int,
        issued_now: np.ndarray,
        options: QEIOptions,
    ) -> tuple[np.ndarray, list[dict[str, Any]]]:
        first = request.count - q
        X = np.asarray(request.X, dtype=np.float64).reshape(-1, request.dim)
        y = np.asarray(request.y, dtype=np.float64).reshape(-1)
        usable = np.isfinite(y) & np.all(np.isfinite(X), axis=1)
        X, y = X[usable], y[usable]
        n_dropped = int((~usable).sum())
        observed_Z = model_inputs(X, bounds, request.structure)
        n_distinct = _n_distinct(observed_Z)
        if n_distinct < 2:
            return self._fallback(
                request, bounds, first, q, f"fewer than 2 distinct observed points ({n_distinct})"
            )
        y_scale = max(1.0, float(np.max(np.abs(y))))
        if float(np.ptp(y)) <= 1e-12 * y_scale:
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

        import botorch  # noqa: F401  (an import error is a broken install, not a fallback)

        cpu_started = time.thread_time()
        try:
            with _LOCK, warnings.catch_warnings():
                warnings.simplefilter("ignore")
                rows, extra = self._optimise(request, bounds, X, y, X_pending, q, options)
        except Exception as error:  # any numerical failure must degrade, not crash the ask
            return self._fallback(
                request, bounds, first, q, f"model failed: {type(error).__name__}: {error}"[:300]
            )

        extra.update(
            cpu_seconds=round(time.thread_time() - cpu_started, 4),
            n_train=len(y),
            n_distinct=n_distinct,
            n_pending=len(X_pending),
            n_dropped=n_dropped,
        )
        if len(y) > n_distinct:
            extra["duplicate_points"] = len(y) - n_distinct
        methods = extra.pop("methods")
        infos: list[dict[str, Any]] = []
        rows_Z = model_inputs(rows, bounds, request.structure)
        taken = [observed_Z, model_inputs(X_pending, bounds, request.structure)]
        taken = taken if not request.noisy else []
        sobol_rows, sobol_info = self._fallback(request, bounds, first, q, "duplicate candidate")
        for i in range(q):
            stack = np.concatenate([*taken, rows_Z[:i]], axis=0)
            if _nearest_distance(stack, rows_Z[i]) < _DUPLICATE_CANDIDATE_TOL:
                rows[i] = sobol_rows[i]
                rows_Z[i] = model_inputs(sobol_rows[i], bounds, request.structure)[0]
                infos.append({**sobol_info[i], **extra, "method": "sobol-fallback"})
            else:
                infos.append({"proposer": self.name, **extra, "method": methods[i]})
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
    ) -> tuple[np.ndarray, dict[str, Any]]:
        import torch
        from botorch.acquisition.logei import (
            qLogExpectedImprovement,
            qLogNoisyExpectedImprovement,
        )
        from botorch.models import SingleTaskGP
        from botorch.models.transforms.outcome import Standardize
        from botorch.sampling.normal import SobolQMCNormalSampler
        from botorch.utils.sampling import manual_seed

        from adservice.proposers.acquisition import MixedDomain, maximise
        from adservice.proposers.gpmodel import (
            AnalyticLogEI,
            design_kernel,
            fit_map,
            structure_correlation,
            structure_lengthscale,
        )

        if torch.get_num_threads() != _TORCH_THREADS:
            torch.set_num_threads(_TORCH_THREADS)
        device_name = options.device or ("cuda" if torch.cuda.is_available() else "cpu")
        device = torch.device(device_name)
        tkw: dict[str, Any] = {"dtype": torch.float64, "device": device}
        search = request.structure
        seed = derived_seed(request.seed, request.n_issued)

        Z = model_inputs(X, bounds, search)
        spec_dim = Z.shape[1] - 1
        train_Z = torch.as_tensor(Z, **tkw)
        train_Y = torch.as_tensor(y, **tkw).unsqueeze(-1)
        noise_mode = options.noise or ("inferred" if request.noisy else "floor")
        train_Yvar = None
        likelihood = None
        if noise_mode == "fixed":
            # Standardize divides Yvar by var(y): this is a variance of 1e-6 after scaling.
            train_Yvar = torch.full_like(train_Y, 1e-6 * max(float(np.var(y)), 1e-12))
        elif noise_mode == "floor":
            from gpytorch.constraints import GreaterThan
            from gpytorch.likelihoods import GaussianLikelihood

            likelihood = GaussianLikelihood(
                noise_constraint=GreaterThan(1e-6, transform=None, initial_value=1e-4)
            )
            likelihood = likelihood.to(**tkw)
        kernel = options.kernel
        model = SingleTaskGP(
            train_Z,
            train_Y,
            train_Yvar=train_Yvar,
            likelihood=likelihood,
            covar_module=design_kernel(search, spec_dim, kernel=kernel, **tkw),
            outcome_transform=Standardize(m=1),
        )

        layout_key = _layout_key(search)
        data_key = hashlib.sha256(
            b"".join(
                [
                    X.tobytes(),
                    y.tobytes(),
                    bounds.tobytes(),
                    layout_key,
                    f"{noise_mode}/{kernel}".encode(),
                ]
            )
        ).hexdigest()
        study_key = (
            bounds.tobytes(),
            layout_key,
            request.seed,
            request.n_initial,
            noise_mode,
            kernel,
            # the first observations: two studies of one box and seed are not one study
            X[:2].tobytes(),
            y[:2].tobytes(),
        )
        use_warm = options.warm_start

        started = time.perf_counter()
        exact = _lru_get(_FITS_BY_DATA, data_key) if use_warm else None
        if exact is not None:
            model.load_state_dict(_to_device(exact, device), strict=False)
            fit_source = "cached"
        else:
            previous = _lru_get(_FITS_BY_STUDY, study_key) if use_warm else None
            fit_source = "cold"
            if previous is not None:
                model.load_state_dict(_to_device(previous, device), strict=False)
                fit_source = "warm"
            with manual_seed(seed):
                fit_map(model)
            params = {name: p.detach().cpu().clone() for name, p in model.named_parameters()}
            if not all(torch.isfinite(p).all() for p in params.values()):
                raise FloatingPointError("non-finite hyperparameters after the fit")
            _lru_put(_FITS_BY_DATA, data_key, params)
            _lru_put(_FITS_BY_STUDY, study_key, params)
        model.eval()
        fit_seconds = time.perf_counter() - started

        if options.num_restarts is not None:
            num_restarts = options.num_restarts
        else:
            num_restarts = min(DEFAULT_RESTARTS, options.raw_samples or DEFAULT_RESTARTS)
        raw_count = options.raw_samples or max(DEFAULT_RAW_SAMPLES, num_restarts)
        mc_samples = options.mc_samples or 128
        domain = MixedDomain(
            used=search.used if search is not None else np.ones((1, spec_dim), dtype=bool),
            pad=search.pad if search is not None else 0.5,
        )
        incumbents = Z[np.argsort(-y, kind="stable")]
        pending_Z = model_inputs(X_pending, bounds, search) if len(X_pending) else Z[:0]
        chosen: list[np.ndarray] = []
        methods: list[str] = []
        values: list[float] = []
        switched = 0
        started = time.perf_counter()
        analytic = (
            AnalyticLogEI(model, train_Z, y, request.noisy)
            if options.acquisition == "analytic"
            else None
        )
        for step in range(q):
            step_seed = derived_seed(seed, step)
            batch_pending = np.concatenate([pending_Z, *[z[None, :] for z in chosen]])
            pending_t = torch.as_tensor(batch_pending, **tkw) if len(batch_pending) else None
            acqf: Any
            with manual_seed(step_seed):
                if analytic is not None:
                    acqf, method = analytic.step(pending_t)
                else:
                    sampler = SobolQMCNormalSampler(
                        sample_shape=torch.Size([mc_samples]), seed=step_seed
                    )
                    if request.noisy:
                        acqf = qLogNoisyExpectedImprovement(
                            model=model,
                            X_baseline=train_Z,
                            sampler=sampler,
                            X_pending=pending_t,
                            prune_baseline=True,
                        )
                        method = "qLogNEI"
                    else:
                        acqf = qLogExpectedImprovement(
                            model=model, best_f=float(y.max()), sampler=sampler, X_pending=pending_t
                        )
                        method = "qLogEI"
                optimum = maximise(
                    acqf,
                    domain,
                    raw_count=raw_count,
                    num_restarts=num_restarts,
                    maxiter=options.maxiter,
                    seed=step_seed,
                    incumbents=incumbents,
                    tkw=tkw,
                )
            chosen.append(optimum.z)
            methods.append(method)
            values.append(optimum.value)
            switched += optimum.structures_switched
        acq_seconds = time.perf_counter() - started
        rows_np = search_vectors(np.array(chosen), bounds, search)
        if not np.all(np.isfinite(rows_np)):
            raise FloatingPointError("non-finite candidates from the acquisition optimiser")
        extra: dict[str, Any] = {
            "methods": methods,
            "log_acq_value": values[0] if np.isfinite(values[0]) else None,
            "fit": fit_source,
            "fit_seconds": round(fit_seconds, 4),
            "acq_seconds": round(acq_seconds, 4),
            "num_restarts": num_restarts,
            "raw_samples": raw_count,
            "device": device.type,
        }
        if search is not None and search.n_structures > 1:
            extra["structure_lengthscale"] = structure_lengthscale(model)
            extra["structure_correlation"] = structure_correlation(model, search, tkw)
            extra["structures_switched"] = switched
        return rows_np, extra


def _canonical(candidates: np.ndarray, bounds: np.ndarray, request: ProposalRequest) -> np.ndarray:
    """Candidates in the box; for a design space, as the designs they stand for: an
    integral structure index and unused slots at the pad (Sobol points included)."""
    candidates = np.clip(candidates, bounds[0], bounds[1])
    if request.structure is None:
        return candidates
    return search_vectors(
        model_inputs(candidates, bounds, request.structure), bounds, request.structure
    )


def _layout_key(search: SearchStructure | None) -> bytes:
    """What distinguishes one study's model layout from another's in the fit caches."""
    if search is None:
        return b"box"
    axes = repr(
        [(a.theta, a.phi, a.theta_fixed, a.phi_fixed, a.sign_invariant) for a in search.axes]
    )
    return b"".join([search.structure_coords.tobytes(), search.used.tobytes(), axes.encode()])


def _nearest_distance(points: np.ndarray, point: np.ndarray) -> float:
    """Max-norm distance from ``point`` to the nearest row of ``points`` (inf if none)."""
    if len(points) == 0:
        return float("inf")
    return float(np.min(np.max(np.abs(points - point), axis=1)))


def _to_device(params: dict[str, torch.Tensor], device: torch.device) -> dict[str, torch.Tensor]:
    return {name: tensor.to(device) for name, tensor in params.items()}
