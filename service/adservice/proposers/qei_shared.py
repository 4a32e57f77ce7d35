"""What qei shares with the modules it drives (gpfit, greedy, multiobjective), below
them all so none imports another's privates: qei's options, torch's thread limits, the
Monte Carlo lock, the proposer's device and the sizes that qei's memory estimate and
the multi-objective acquisitions agree on."""

from __future__ import annotations

import threading
from typing import Any, Literal

from pydantic import Field, field_validator, model_validator

from adservice.proposers.base import ProposerOptions
from adservice.settings import get_settings

MC_LOCK = threading.Lock()
"""Held by a Monte Carlo acquisition while it optimises (its samplers' state is shared)."""
_THREAD = threading.local()
TORCH_THREADS = get_settings().torch_threads
PROPOSER_DEVICE = get_settings().proposer_device
GPU_MEMORY_SHARE = get_settings().ask_gpu_memory_share

MO_RAW_SAMPLES = 1024
"""Sobol points the starts of a multi-objective or constrained acquisition come from,
unless ``options["raw_samples"]`` says (Ax's default for these acquisitions; qei's 2048
for one objective)."""
MO_SCREEN_DRAWS = 16
"""Posterior draws of the cheaper acquisition that scores the raw samples of a Monte
Carlo multi-objective acquisition (``acquisition.maximise``'s ``screen``); the local
searches use all of them."""
EHVI_CHUNK = 1 << 20
"""Candidates x hypervolume cells x objectives that analytic LogEHVI computes at once
(``multiobjective``; the rest in further chunks): each of its arrays stays under 8 MB."""


def limit_threads(torch: Any) -> None:
    """torch's intra-op threads (OpenMP: a per-thread setting) and the BLAS's (global
    for OpenBLAS) for this thread, once: every thread sets the same values and none
    restores them, so concurrent asks cannot leave each other with the wrong count."""
    if getattr(_THREAD, "limited", False):
        return
    from threadpoolctl import threadpool_limits

    if torch.get_num_threads() != TORCH_THREADS:
        torch.set_num_threads(TORCH_THREADS)
    threadpool_limits(limits=1, user_api="blas")  # L-BFGS-B's small products only contend
    _THREAD.limited = True


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
    second_looks: Literal["thompson", "off", "judged", "always"] = Field(
        default="thompson",
        description="design spaces: how a tree whose first designs were poor gets another "
        "look. thompson (the default): every second model candidate after the start of a "
        "space of at most 16 trees, a random design of the tree one posterior draw "
        "favours, unless it is the incumbent's or has 3 designs (initial.thompson_turn, "
        "looks.drawn_tree); judged and always: every second model candidate while a tree "
        "has one design chooses among those whose best may beat the incumbent "
        "(looks.tree_chances), or among all of them (initial.second_look); off: never "
        "(true and false: always and off); bench/RESULTS.md has each one's figures",
    )
    floor_looks: bool = Field(
        default=True,
        description="with second_looks: thompson, a look turn whose posterior draw favours "
        "the incumbent's tree (or a spent one) gives one more random design to a tree whose "
        "one design scored on the start's floor (the bottom tenth of the start's range; "
        "initial.floor_trees), at random among them; false: such a turn is the model's "
        "free choice, as before issue 61",
    )
    max_train: int | None = Field(
        default=None,
        ge=16,
        le=100_000,
        description="observations the model trains on at most: past it, the best, those "
        "nearest the best and a random rest (adservice.proposers.subset), or a trust "
        "region (large_history). Default: the most the ask's memory budget "
        "(AD_ASK_MEMORY_MB) holds, at most 2048 on cpu and 4096 on cuda",
    )
    large_history: Literal["trust-region", "subset"] | None = Field(
        default=None,
        description="past max_train observations of a continuous box with one outcome: "
        "a GP of the best observations and others near the best, searched in a trust "
        "region around the best (adservice.proposers.trust_region), or a GP of a subset "
        "searched over the whole box (adservice.proposers.subset, what other studies "
        "get). Default: the subset, "
        "the trust region past 20,000 observations",
    )
    device: Literal["cpu", "cuda"] | None = Field(
        default=None, description="Default: the server's AD_PROPOSER_DEVICE (cpu unless set)"
    )

    @field_validator("second_looks", mode="before")
    @classmethod
    def _looks_flag(cls, value: Any) -> Any:
        if value is True:
            return "always"
        return "off" if value is False else value

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
