"""An ask's memory budget (``AD_ASK_MEMORY_MB``; for a study whose model runs on cuda,
the larger of it and ``AD_ASK_GPU_MEMORY_SHARE`` of the GPU: ``memory.device_budget``):
refuse, naming the option or the count, what would take more memory than the server
allows; proposers estimate their own need."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from adclient.objectives import Outcomes
from adclient.schemas import ProposerConfig
from adservice.errors import InvalidError
from adservice.proposers import options_model, proposer_class
from adservice.repository.studies import History
from adservice.services.configs import StudyConfig
from adservice.settings import get_settings


def _memory_need(
    config: ProposerConfig,
    *,
    dim: int,
    count: int,
    n_train: int,
    n_pending: int,
    n_failed: int = 0,
    outcomes: Outcomes | None = None,
) -> Any:
    """The proposer's estimate of an ask's peak memory (``proposers.memory.MemoryNeed``), or None
    for proposers whose memory does not grow with their options; a model per objective
    and per constraint of ``outcomes``."""
    estimate = getattr(proposer_class(config.name), "memory_need", None)
    if estimate is None:
        return None
    outcomes = outcomes or Outcomes()
    return estimate(
        config.options,
        dim=dim,
        count=count,
        n_train=n_train,
        n_pending=n_pending,
        n_failed=n_failed,
        n_objectives=outcomes.count,
        n_constraints=len(outcomes.constraints),
    )


def _over_budget(need: Any, budget: int) -> str:
    return (
        f"an ask would need {need.describe()}, more than this server allows per ask "
        f"({budget / 2**20:.0f} MB, AD_ASK_MEMORY_MB; on cuda at least "
        "AD_ASK_GPU_MEMORY_SHARE of the GPU)"
    )


def _on_device(config: ProposerConfig, budget: int, device_bytes: Callable[[], int] | None) -> int:
    """The budget an ask of ``config`` keeps to on the device its model runs on (the
    study's ``device`` option, else ``AD_PROPOSER_DEVICE``), as the proposer does."""
    from adservice.proposers.memory import device_budget  # reads settings at import

    settings = get_settings()
    device = str(config.options.get("device") or settings.proposer_device)
    share = settings.ask_gpu_memory_share
    return device_budget(budget, device, share, device_bytes) or budget


def check_options_memory(
    config: ProposerConfig,
    *,
    dim: int,
    budget: int,
    outcomes: Outcomes | None = None,
    device_bytes: Callable[[], int] | None = None,
) -> None:
    """InvalidError naming the option when one point asked of a study with a few
    observations already exceeds the memory budget (on its device; ``device_bytes``:
    the GPU's memory, by default torch's)."""
    budget = _on_device(config, budget, device_bytes)
    need = _memory_need(config, dim=dim, count=1, n_train=2, n_pending=0, outcomes=outcomes)
    if need is None or need.bytes <= budget:
        return
    named = need.driver in options_model(config.name).model_fields
    path = f"proposer.options.{need.driver}" if named else "proposer.options"
    advice = f"; lower {need.driver}" if named else ""
    problem = f"{path}: {_over_budget(need, budget)}{advice}"
    raise InvalidError(problem, problems=[problem])


def check_ask_memory(
    config: StudyConfig,
    *,
    count: int,
    n_issued: int,
    history: History,
    budget: int,
    device_bytes: Callable[[], int] | None = None,
) -> None:
    """InvalidError naming ``count`` (with the largest count that fits) or the option
    when an ask exceeds the memory budget (on its device, as ``check_options_memory``);
    one that exceeds it through its history alone is left to the proposer, which falls
    back and says why."""
    proposer = config.proposer
    budget = _on_device(proposer, budget, device_bytes)
    model_count = count - min(max(proposer.n_initial - n_issued, 0), count)
    if model_count == 0:
        return

    def need(points: int) -> Any:
        return _memory_need(
            proposer,
            dim=config.dim,
            count=points,
            n_train=len(history.y),
            n_pending=len(history.pending),
            n_failed=len(history.failed),
            outcomes=config.outcomes,
        )

    asked = need(model_count)
    if asked is None or asked.bytes <= budget:
        return
    check_options_memory(proposer, dim=config.dim, budget=budget, device_bytes=device_bytes)
    if need(1).bytes > budget:
        return
    fits = max(c for c in range(1, model_count) if need(c).bytes <= budget)
    problem = (
        f"count: {_over_budget(asked, budget)}; ask at most {fits + count - model_count} "
        "points at a time"
    )
    raise InvalidError(problem, problems=[problem])
