"""A task's or proposer's option errors name the option and say what it takes (issue 39:
a 2-number target read `target.2: Field required`)."""

from __future__ import annotations

import pytest
from pydantic import BaseModel, ConfigDict, ValidationError

from adclient.schemas.config import option_problems


class ReachOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    target: tuple[float, float, float] = (0.0, 0.0, 0.5)
    pair: tuple[float, float] | None = None
    weights: tuple[float, ...] = ()


@pytest.mark.parametrize(
    ("options", "problem"),
    [
        ({"target": [0.1, 0.2]}, "task.options.target: expected 3 items, got 2"),
        ({"target": [0.1]}, "task.options.target: expected 3 items, got 1"),
        ({"pair": [1.0]}, "task.options.pair: expected 2 items, got 1"),
        (
            {"target": [1, 2, 3, 4]},
            "task.options.target: Tuple should have at most 3 items after validation, not 4",
        ),
        ({"weights": "x"}, "task.options.weights: Input should be a valid tuple"),
        (
            {"colour": 1},
            "task.options.colour: unknown option of reach (its options: target, pair, weights)",
        ),
    ],
)
def test_each_problem_names_the_option_and_what_it_takes(
    options: dict[str, object], problem: str
) -> None:
    with pytest.raises(ValidationError) as error:
        ReachOptions.model_validate(options)
    assert option_problems(error.value, ReachOptions, "reach", "task.options") == [problem]
