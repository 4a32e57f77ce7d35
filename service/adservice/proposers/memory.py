"""An ask's peak memory, estimated before it runs from its options and sizes, so the
service can refuse (or fall back) within ``AD_ASK_MEMORY_MB`` instead of running out.
The factors are measured peaks (bench/RESULTS.md, issues 13, 17 and 37); on cuda the
budget is a share of the GPU's memory (``device_budget``)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from adservice.proposers.greedy import DEFAULT_RAW_SAMPLES, DEFAULT_RESTARTS
from adservice.proposers.qei_shared import EHVI_CHUNK, MO_RAW_SAMPLES, MO_SCREEN_DRAWS, QEIOptions
from adservice.proposers.subset import MAX_TRAIN

_FLOAT = 8
_MO_BASELINE = 16
"""Observations assumed in the pruned baseline of qLogNEHVI (typically the front)."""
_SCORED_AT_ONCE = 1024
"""Raw samples scored in one batch (``acquisition._CHUNK``)."""


@dataclass(frozen=True)
class MemoryNeed:
    """An ask's estimated peak memory, and the option (or ``observations``, the
    history) whose arrays are the largest part of it."""

    bytes: int
    driver: str
    sizes: str

    def describe(self) -> str:
        return f"about {self.bytes / 2**20:.0f} MB ({self.sizes}; mostly {self.driver})"


def memory_need(
    options: QEIOptions,
    *,
    dim: int,
    count: int,
    n_train: int,
    n_pending: int,
    n_objectives: int = 1,
    n_constraints: int = 0,
) -> MemoryNeed:
    """Peak memory of an ask beyond the process's own, in float64 arrays: the raw
    samples, one batch of them scored (against every point the last believer
    conditions on, or, for ``mc``, ``mc_samples`` joint draws of the candidate with the
    pending points), the kernel matrices of the fit and of the posterior. The factors
    are measured peaks over those sizes, rounded up (bench/RESULTS.md: the
    estimate against the growth of a fresh process's peak memory)."""
    n_train = min(n_train, options.max_train or MAX_TRAIN)  # a subset past it (subset.py)
    restarts = options.num_restarts or min(DEFAULT_RESTARTS, options.raw_samples or 10**9)
    raw = options.raw_samples or max(DEFAULT_RAW_SAMPLES, restarts)
    batch = min(_SCORED_AT_ONCE, raw)
    conditioned = n_train + n_pending + count
    parts = {
        "raw_samples": _FLOAT * raw * (dim + 1) * 6 + _FLOAT * batch * (conditioned + dim) * 10,
        # the most an ask added, measured (bench/RESULTS.md, issue 37): 43 MB at 512
        # observations, 151 at 1024, 285 at 2048 to 2246, 374 at 3000, 660 at 4096; the
        # estimate is 0.8 to 1.6 times those (16 n^2 + 6 c^2 floats before: 4 to 5 times)
        "observations": _FLOAT * (3 * n_train**2 + 2 * conditioned**2),
    }
    sizes = f"{raw} raw samples of {dim} dimensions, {n_train} observations, {n_pending} pending"
    if options.acquisition == "mc":
        mc = options.mc_samples or 128
        joint = count + n_pending  # the noisy baseline's draws are cached, not per batch
        parts["mc_samples"] = _FLOAT * batch * joint * (10 * mc + 4 * (joint + n_train))
        sizes += f", {mc} MC samples of {joint} points jointly"
    outcomes = n_objectives + n_constraints
    if outcomes > 1 and options.acquisition == "mc":
        # the Monte Carlo acquisitions (``multiobjective``): the raw samples are
        # scored with MO_SCREEN_DRAWS draws of each outcome jointly with the baseline (at
        # most _MO_BASELINE of the observations assumed) and the pending points, against
        # every observation, and a draw's hypervolume cells: an upper estimate from the
        # shapes, checked against a fresh process's peak at n = 80 and 200, 0 and 16
        # pending, 2 and 3 outcomes (65, 123, 334 MB measured; 109, 226, 501 estimated)
        raw = options.raw_samples or max(MO_RAW_SAMPLES, restarts)
        batch = min(_SCORED_AT_ONCE, raw)
        joint = min(n_train, _MO_BASELINE) + n_pending + count
        mc = options.mc_samples or 128
        draws = max(MO_SCREEN_DRAWS, mc * 64 // batch)
        parts["raw_samples"] = _FLOAT * raw * (dim + 1) * 6 + _FLOAT * batch * joint * (
            outcomes * (2 * n_train + 2 * joint + 3 * draws) + 10 * draws * n_objectives
        )
        parts["observations"] *= outcomes
        sizes = (
            f"{raw} raw samples of {dim} dimensions, {n_train} observations, "
            f"{n_pending} pending, {outcomes} outcomes"
        )
    elif outcomes > 1:
        # one posterior per outcome; several objectives add the hypervolume cells, which
        # analytic LogEHVI computes in chunks of EHVI_CHUNK values: checked against the
        # growth of a fresh process's peak (its modules imported) at n = 80, 2
        # objectives (50 MB measured, 40 estimated: the allocator's own overhead, far
        # below any budget), and at n = 200 with 2 objectives and 16 pending, 3 and 4
        # objectives (69 to 91, 128 to 155, 207 to 227 MB measured over repeats; 111,
        # 213, 236 estimated)
        parts["observations"] *= outcomes
        parts["raw_samples"] += _FLOAT * batch * (conditioned + dim) * 10 * (outcomes - 1)
        if n_objectives > 1:
            cells = float(conditioned + 1) ** (n_objectives - 1)
            parts["hypercells"] = _FLOAT * 18 * int(min(batch * cells * n_objectives, EHVI_CHUNK))
        sizes += f", {outcomes} outcomes"
    driver = max(parts, key=lambda name: parts[name])
    return MemoryNeed(bytes=int(sum(parts.values())), driver=driver, sizes=sizes)


def device_budget(
    budget: int | None,
    device: str,
    share: float,
    device_bytes: Callable[[], int] | None = None,
) -> int | None:
    """The bytes an ask may take on ``device`` (None: no limit): ``budget``
    (``AD_ASK_MEMORY_MB``) on cpu; on cuda the larger of it and ``share``
    (``AD_ASK_GPU_MEMORY_SHARE``) of the GPU's memory, ``device_bytes()`` (by default
    torch's total memory of the current GPU). The cuda path has not run on a GPU here:
    its arithmetic is tested with a given ``device_bytes``."""
    if budget is None or device != "cuda":
        return budget
    total = (device_bytes or _cuda_total_bytes)()
    return max(budget, int(share * total))


def _cuda_total_bytes() -> int:
    import torch

    return int(torch.cuda.get_device_properties(torch.cuda.current_device()).total_memory)
