"""bench/paper.py's bookkeeping: evaluations to target with censoring, quantiles, resumption."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from PIL import Image

from bench.paper import METHODS, Cell, grid, main, study_create
from bench.paper_report import best_designs, picture_label
from bench.paper_stats import Study, _ratio, summarise
from bench.paperlib import append_jsonl, quantiles, read_jsonl


def _study(values: list[float | None], target: float = 1.0, budget: int | None = None) -> Study:
    trials = [
        {
            "number": n,
            "state": "failed" if v is None else "complete",
            "value": v,
            "finished_s": 10.0 * (n + 1),
            "worker_s": 1.0,
        }
        for n, v in enumerate(values)
    ]
    record = {
        "task": "stand-up",
        "method": "qei",
        "learner": "fast",
        "seed": 0,
        "budget": budget or len(values),
        "wall_s": 5.0,
        "trials": list(reversed(trials)),  # order comes from the numbers, not the list
    }
    return Study(record, target)


def test_evaluations_to_target_counts_failed_trials_and_censors() -> None:
    study = _study([0.2, None, 0.5, 1.2, 3.0])
    assert study.evals_to_target == 4
    assert study.time_to_target == 40.0
    assert study.best_within(3) == 0.5
    assert list(study.best_so_far(5)) == [0.2, 0.2, 0.5, 1.2, 3.0]
    never = _study([0.1, 0.2])
    assert never.evals_to_target == math.inf
    assert math.isnan(never.time_to_target)
    assert math.isnan(_study([0.1], target=None).evals_to_target)  # type: ignore[arg-type]


def test_quantiles_fall_on_censored_values_as_infinite() -> None:
    assert quantiles([1.0, 2.0, 3.0, 4.0, 5.0]) == [2.0, 3.0, 4.0]
    assert quantiles([1.0, 2.0, math.inf, math.inf, math.inf]) == [2.0, math.inf, math.inf]
    # between a finite value and a censored one: censored
    assert quantiles([1.0, math.inf], (0.5,)) == [math.inf]
    assert quantiles([1.0, 3.0, math.inf], (0.5,)) == [3.0]


def test_summary_and_ratio_with_a_censored_baseline() -> None:
    qei = summarise([_study([0.0, 0.0, 2.0]), _study([0.0, 2.0, 0.0]), _study([0.0] * 3)])
    assert qei["median"] == 3.0 and qei["early"] == 2 and qei["within"] == 2
    baseline = summarise([_study([0.0] * 30)] * 3)
    assert baseline["median"] == math.inf
    assert "met" in _ratio(baseline, qei, 3)  # > 31/3 >= 3
    assert "undecided" in _ratio(summarise([_study([0.0] * 5)] * 3), qei, 3)  # > 6/3 only
    close = summarise([_study([0.0] * 5 + [2.0])] * 3)
    assert "missed" in _ratio(close, qei, 3)  # 6/3 = 2 < 3


def test_grid_runs_onehot_only_where_there_are_several_structures() -> None:
    cells = grid(["stand-up", "lift-highest"], list(METHODS), "fast", 2, 15, 30)
    assert {c.method for c in cells if c.task == "stand-up"} == set(METHODS) - {"qei-onehot"}
    assert {c.method for c in cells if c.task == "lift-highest"} == set(METHODS)
    assert {c.budget for c in cells if c.method.startswith("qei")} == {15}
    assert {c.budget for c in cells if not c.method.startswith("qei")} == {30}
    assert len({c.key for c in cells}) == len(cells) == 2 * (5 + 6)  # qei-mixed on both
    assert [c.seed for c in cells] == sorted(c.seed for c in cells)  # seed-major


def test_jsonl_skips_a_line_cut_short(tmp_path: Path) -> None:
    path = tmp_path / "results.jsonl"
    append_jsonl(path, {"key": "a"})
    with path.open("a") as handle:
        handle.write('{"key": "b", "tri')  # a crash mid-write
    assert read_jsonl(path) == [{"key": "a"}]
    append_jsonl(path, {"key": "c"})  # the next record starts a line of its own
    assert read_jsonl(path) == [{"key": "a"}, {"key": "c"}]
    assert read_jsonl(tmp_path / "missing.jsonl") == []


def test_space_override_reaches_the_study_body_and_needs_a_tag(
    capsys: pytest.CaptureFixture[str],
) -> None:
    cell = Cell("lift-highest", "qei", "fast", 3, 15, "d30")
    body = study_create(cell, None, {"embedding_max_dim": 30})
    assert body["space"]["embedding_max_dim"] == 30
    assert body["proposer"]["seed"] == body["task"]["seed"] == 3
    assert "embedding_max_dim" not in study_create(cell, None)["space"]
    with pytest.raises(SystemExit):
        main(["--space", "embedding_max_dim=30"])
    assert "--tag" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--tag", "x", "--space", "embedding_max_dim"])
    assert "KEY=VALUE" in capsys.readouterr().err


def test_a_best_design_copy_stands_in_only_for_the_design_it_shows(tmp_path: Path) -> None:
    """The report copies a study's best-design picture labelled with the evaluation it
    shows; once the run's own picture is gone the copy stands in for that evaluation,
    never for a later best whose picture is gone too."""
    source = tmp_path / "run" / "robot.png"
    source.parent.mkdir()
    Image.new("RGB", (4, 3), (200, 10, 10)).save(source)
    folder = tmp_path / "figures"
    folder.mkdir()
    study = _study([0.2, 0.9])
    study.record.update(
        best={"value": 0.9, "number": 1, "params": {"structure": "a-b,b-c"}}, png=str(source)
    )
    (row,) = best_designs([study], "fast", folder)
    assert "0.9000 (seed 0, evaluation 2)" in row and "paper/best-stand-up-qei-fast.png" in row
    copy = folder / "best-stand-up-qei-fast.png"
    assert picture_label(copy) == "stand-up qei fast seed 0 number 1"
    source.unlink()
    assert best_designs([study], "fast", folder) == [row]
    study.record["best"] = {"value": 1.1, "number": 5, "params": {"structure": "a-b"}}
    assert best_designs([study], "fast", folder) == []
