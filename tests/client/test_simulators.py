"""``task.simulator`` (issue 59): the engine a study names is one of ``SIMULATORS`` and one
its task declares (``TaskSpec.simulators``), checked when a study is created; a stored
task without the field, or with a name no longer known, still loads."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from adclient.plugins import SIMULATORS, SimulatorOptions, TaskSpec, catalogue
from adclient.schemas import NewTaskConfig, TaskConfig


def test_every_built_in_task_runs_on_both_engines_pybullet_by_default() -> None:
    assert SIMULATORS == ("pybullet", "mujoco")
    for name, spec in catalogue().tasks.items():
        assert spec.simulators == SIMULATORS, name
        assert NewTaskConfig(name=name).simulator == "pybullet"
        assert NewTaskConfig(name=name, simulator="mujoco").simulator == "mujoco"


def test_a_simulator_that_is_not_one_is_refused_naming_the_engines() -> None:
    with pytest.raises(ValidationError) as refused:
        NewTaskConfig(name="stand-up", simulator="bogus")
    (error,) = refused.value.errors()
    assert error["loc"] == ("simulator",)
    assert "'bogus' is not a simulator (simulators: pybullet, mujoco)" in error["msg"]
    # an external task's engine is its workers' own, but still one of the names
    assert NewTaskConfig(name="mine", external=True, simulator="mujoco").simulator == "mujoco"
    with pytest.raises(ValidationError, match="'gazebo' is not a simulator"):
        NewTaskConfig(name="mine", external=True, simulator="gazebo")


def test_stored_tasks_load_with_or_without_the_field() -> None:
    assert TaskConfig.model_validate({"name": "stand-up"}).simulator == "pybullet"
    # a stored name no longer known loads; its trials fail in the worker, saying why
    assert TaskConfig.model_validate({"name": "x", "simulator": "old"}).simulator == "old"
    # the job leaves the default out, so a worker older than the field reads it
    assert "simulator" not in NewTaskConfig(name="stand-up").model_dump(exclude_defaults=True)


def test_a_task_declares_the_default_engine_and_known_ones_only() -> None:
    def spec(simulators: tuple[str, ...]) -> TaskSpec:
        return TaskSpec(
            name="t",
            options=SimulatorOptions,
            description="",
            factory="x:y",
            simulators=simulators,
        )

    assert spec(("pybullet",)).simulators == ("pybullet",)
    for wrong in (("mujoco",), ("pybullet", "gazebo"), ()):
        with pytest.raises(TypeError, match="simulators must include 'pybullet'"):
            spec(wrong)
