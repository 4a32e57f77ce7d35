"""Fitting one outcome's GP for ``qei``, through two small in-process LRU caches.

Fitted hyperparameters are kept by a digest of the exact training data (an identical
request re-uses the exact fit, so it gives bit-identical candidates) and by the
study's identity (the next ask of the same study warm-starts its fit from the
previous optimum; see ``qei``'s docstring for why another study of the same box
never does). Imported only when a proposal is computed (it imports torch).
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from adservice.proposers.base import ProposalRequest, SearchStructure, model_inputs

if TYPE_CHECKING:
    from adservice.proposers.qei_shared import QEIOptions

_CACHE_LOCK = threading.Lock()
_CACHE_SIZE = 256
_FITS_BY_DATA: OrderedDict[str, dict[str, torch.Tensor]] = OrderedDict()
_FITS_BY_STUDY: OrderedDict[tuple[Any, ...], dict[str, torch.Tensor]] = OrderedDict()
WARM_MAXITER = 50
"""L-BFGS-B iterations of a fit warm-started from the study's previous one (a cold fit
has 200): one new observation moves the optimum little, and the next ask goes on from
where this one stopped. On the 8-tree suite space at n = 30 a warm fit took 50 to 210
likelihood evaluations to converge, the same candidates' acquisition values within
0.03 in log space with this cap."""
FIT_POINTS = 300
"""The most observations a GP's hyperparameters are fitted on (``fit_subset``)."""
FIT_BEST = 75
"""Of those, the best observations always in."""


def clear_caches() -> None:
    """Forget every cached fit (tests and benchmarks measure cold starts with it)."""
    with _CACHE_LOCK:
        _FITS_BY_DATA.clear()
        _FITS_BY_STUDY.clear()


def _lru_put(cache: OrderedDict, key: Any, value: Any) -> None:
    with _CACHE_LOCK:
        cache[key] = value
        cache.move_to_end(key)
        while len(cache) > _CACHE_SIZE:
            cache.popitem(last=False)


def _lru_get(cache: OrderedDict, key: Any) -> Any:
    with _CACHE_LOCK:
        value = cache.get(key)
        if value is not None:
            cache.move_to_end(key)
        return value


def fit_outcome(
    request: ProposalRequest,
    options: QEIOptions,
    bounds: np.ndarray,
    X: np.ndarray,
    y: np.ndarray,
    tkw: dict[str, Any],
    deadline: float | None,
    outcome: str = "",
    history: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[Any, str]:
    """A ``SingleTaskGP`` on one outcome ``y`` of the points ``X`` (the study's model:
    ``gpmodel.design_kernel``, the noise mode, outcomes standardised) with its
    hyperparameters fitted by ``likelihood.fit_map`` through the fit caches, in eval mode;
    and where its fit came from (cached, warm, cold; ``-subset-N`` when a long history's
    hyperparameters were fitted on N of its observations, ``fit_subset``; ``-stopped``
    past the deadline).
    ``outcome`` names the outcome in the cache keys ("" for the one objective, else
    e.g. ``objective 1`` or ``constraint 0``): each outcome of a study is fitted and
    warm-started on its own. ``history``: the study's whole history (points, outcome)
    when ``X`` and ``y`` are a subset of it (``subset.training_subset``); the
    hyperparameters are then fitted on ``fit_subset`` of the history, which stays the
    same from ask to ask (the training subset's random part does not), so the next ask
    re-uses the fit or warm-starts it."""
    import torch
    from botorch.models import SingleTaskGP
    from botorch.models.transforms.outcome import Standardize

    from adservice.proposers.acquisition import past
    from adservice.proposers.gpmodel import design_kernel
    from adservice.proposers.likelihood import fit_map

    search = request.structure
    device = tkw["device"]
    Z = model_inputs(X, bounds, search)
    spec_dim = Z.shape[1] - 1
    train_Z = torch.as_tensor(Z, **tkw)
    train_Y = torch.as_tensor(y, **tkw).unsqueeze(-1)
    noise_mode = options.noise or ("inferred" if request.noisy else "floor")
    kernel = options.kernel
    # several objectives: the unit length-scale prior (gpmodel.UNIT_LENGTHSCALE_PRIOR)
    objectives = request.objectives
    unit_prior = objectives is not None and np.ndim(objectives) == 2 and objectives.shape[1] > 1

    def gp(train_Z: torch.Tensor, train_Y: torch.Tensor) -> Any:
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
            ).to(**tkw)
        return SingleTaskGP(
            train_Z,
            train_Y,
            train_Yvar=train_Yvar,
            likelihood=likelihood,
            covar_module=design_kernel(
                search,
                spec_dim,
                kernel=kernel,
                categories=request.box.categorical if request.box is not None else None,
                unit_prior=unit_prior,
                **tkw,
            ),
            outcome_transform=Standardize(m=1),
        )

    model = gp(train_Z, train_Y)
    fit_X, fit_y = (X, y) if history is None else history
    # a training subset is half its best (subset.training_subset): so is the fit's rest
    subset = fit_subset(fit_y, request.seed, good=0 if history is None else len(y) // 2)
    if subset is None and history is not None:
        subset = np.arange(len(fit_y))
    if subset is None:
        fitted = model
    else:
        fit_X, fit_y = fit_X[subset], fit_y[subset]
        fitted = gp(
            torch.as_tensor(model_inputs(fit_X, bounds, search), **tkw),
            torch.as_tensor(fit_y, **tkw).unsqueeze(-1),
        )

    layout_key = _layout_key(search, request)
    # the fit's data: what the hyperparameters depend on (with a fit subset, it alone)
    data_key = hashlib.sha256(
        b"".join(
            [
                fit_X.tobytes(),
                fit_y.tobytes(),
                bounds.tobytes(),
                layout_key,
                f"{noise_mode}/{kernel}/{outcome}/{unit_prior}".encode(),
                np.var(y).tobytes() if noise_mode == "fixed" else b"",
            ]
        )
    ).hexdigest()
    first_X, first_y = (X, y) if history is None else history
    study_key = (
        bounds.tobytes(),
        layout_key,
        request.seed,
        request.n_initial,
        noise_mode,
        kernel,
        outcome,
        unit_prior,
        # the first observations: two studies of one box and seed are not one study
        first_X[:2].tobytes(),
        first_y[:2].tobytes(),
    )
    use_warm = options.warm_start

    exact = _lru_get(_FITS_BY_DATA, data_key) if use_warm else None
    if exact is not None:
        model.load_state_dict(_to_device(exact, device), strict=False)
        fit_source = "cached"
    else:
        previous = _lru_get(_FITS_BY_STUDY, study_key) if use_warm else None
        fit_source = "cold"
        if previous is not None:
            fitted.load_state_dict(_to_device(previous, device), strict=False)
            fit_source = "warm"
        fit_map(fitted, deadline=deadline, maxiter=WARM_MAXITER if previous is not None else 200)
        params = {name: p.detach().cpu().clone() for name, p in fitted.named_parameters()}
        if fitted is not model:
            model.load_state_dict(_to_device(params, device), strict=False)
            fit_source += f"-subset-{len(subset)}"  # type: ignore[arg-type]
        if not all(torch.isfinite(p).all() for p in params.values()):
            raise FloatingPointError("non-finite hyperparameters after the fit")
        if past(deadline):
            fit_source += "-stopped"  # not the exact fit: a warm start, never a reuse
        else:
            _lru_put(_FITS_BY_DATA, data_key, params)
        _lru_put(_FITS_BY_STUDY, study_key, params)
    model.eval()
    return model, fit_source


def fit_subset(y: np.ndarray, seed: int, good: int = 0) -> np.ndarray | None:
    """The observations a large history's hyperparameters are fitted on (None: all of
    them): the ``FIT_BEST`` best and a seeded sample of the rest, ``FIT_POINTS`` in all.
    Each likelihood evaluation of the fit factors an n x n matrix, a few hundred times
    a fit; the posterior the acquisition uses still conditions on every observation
    with those hyperparameters, so only their estimate loses data (bench/RESULTS.md
    measures what that costs). The sample is the rest's lowest of one seeded stream of
    priorities, one per observation in the order told: a new observation keeps the
    earlier ones' priorities, so the next ask's sample differs only where a new
    observation is among the best or draws a low priority, and its fit is cached or
    warm-started from one on nearly the same data. ``good``: half the rest's sample
    comes from the ``good`` best (past the ``FIT_BEST``), as a training subset's half
    of its best and nearest the best would give (a sample of the whole history alone
    closed less of the gap on Hartmann6 at 10,000, bench/RESULTS.md)."""
    if len(y) <= FIT_POINTS:
        return None
    order = np.argsort(-y, kind="stable")
    rest = order[FIT_BEST:]
    priority = np.random.default_rng([seed, 0xF17]).random(len(y))
    count = FIT_POINTS - FIT_BEST
    pools = [rest]
    if good > FIT_BEST + count // 2:
        pools, count = [order[FIT_BEST:good], order[good:]], count // 2
    lowest = [
        pool[np.argsort(priority[pool], kind="stable")[:take]]
        for pool, take in zip(pools, [count, FIT_POINTS - FIT_BEST - count], strict=False)
    ]
    return np.sort(np.concatenate([order[:FIT_BEST], *lowest]))


def _layout_key(search: SearchStructure | None, request: ProposalRequest) -> bytes:
    """What distinguishes one study's model layout from another's in the fit caches."""
    if search is None and request.box is not None:
        return f"box/{request.box.ordinal}/{sorted(request.box.categorical.items())}".encode()
    if search is None:
        return b"box"
    axes = repr(
        [(a.theta, a.phi, a.theta_fixed, a.phi_fixed, a.sign_invariant) for a in search.axes]
    )
    return b"".join([search.structure_coords.tobytes(), search.used.tobytes(), axes.encode()])


def _to_device(params: dict[str, torch.Tensor], device: torch.device) -> dict[str, torch.Tensor]:
    return {name: tensor.to(device) for name, tensor in params.items()}
