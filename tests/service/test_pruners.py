"""The pruners alone: pure decisions on arrays, checked against Optuna's rules."""

from __future__ import annotations

import numpy as np

from adclient.pruning import AshaOptions, MedianOptions, PrunerConfig
from adservice.pruners import Curve, PruneRequest, should_stop
from adservice.pruners.asha import promotable, rungs


def curve(state: str, points: dict[int, float]) -> Curve:
    steps = sorted(points)
    return Curve(state, np.asarray(steps, dtype=np.int64), np.asarray([points[s] for s in steps]))


def request(step: int, value: float, before: list[int], others: list[Curve]) -> PruneRequest:
    return PruneRequest(
        step=step,
        value=value,
        previous_steps=np.asarray(before, dtype=np.int64),
        best=value,
        others=others,
    )


def test_median_checks_only_the_first_report_past_each_interval_step() -> None:
    config = PrunerConfig(
        name="median", options={"n_startup_trials": 1, "n_warmup_steps": 2, "interval_steps": 4}
    )
    done = [curve("complete", {s: 10.0 for s in range(20)})]
    assert should_stop(config, request(1, 0.0, [0], done)) is False  # warm-up
    assert should_stop(config, request(2, 0.0, [1], done)) is True  # 2 is a pruning step
    assert should_stop(config, request(4, 0.0, [2, 3], done)) is False  # 2 < 4 < 6
    assert should_stop(config, request(7, 0.0, [4], done)) is True  # first past 6
    # Running and pruned trials are not in the median; without complete ones, no pruning.
    running = [curve("running", {7: 10.0}), curve("pruned", {7: 10.0})]
    assert should_stop(config, request(7, 0.0, [4], running)) is False


def test_median_waits_for_a_value_at_the_same_step() -> None:
    options = MedianOptions(n_startup_trials=1, n_min_trials=2)
    config = PrunerConfig(name="median", options=options.model_dump())
    others = [curve("complete", {10: 5.0}), curve("complete", {20: 5.0})]
    assert should_stop(config, request(10, 0.0, [], others)) is False  # one value at 10
    others.append(curve("complete", {10: 7.0}))
    assert should_stop(config, request(10, 0.0, [], others)) is True


def test_asha_rungs_and_promotion_rule() -> None:
    options = AshaOptions(min_resource=100, reduction_factor=3, max_resource=2700)
    assert list(rungs(options, above=-1, up_to=10_000)) == [100, 300, 900]
    assert list(rungs(options, above=100, up_to=899)) == [300]
    assert promotable(1.0, [1.0], 3) and promotable(2.0, [1.0, 2.0, 0.0], 3)
    assert not promotable(1.0, [1.0, 2.0, 0.0], 3)
    six = [3.0, 2.0, 1.0, 0.0, -1.0, -2.0]  # 6 // 3 - 1 = 1: the top two go on
    assert promotable(2.0, six, 3) and not promotable(1.0, six, 3)
    config = PrunerConfig(name="asha", options=options.model_dump())
    # A report jumping over two rungs must pass both.
    others = [curve("running", {100: 0.0, 300: 5.0})]
    assert should_stop(config, request(300, 1.0, [50], others)) is True  # fails rung 300
    assert should_stop(config, request(300, 6.0, [50], others)) is False
    bootstrap = PrunerConfig(name="asha", options={"min_resource": 1, "bootstrap_count": 1})
    assert should_stop(bootstrap, request(1, 9.0, [], [])) is True  # rung needs 2 values
