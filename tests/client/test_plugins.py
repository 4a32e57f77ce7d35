"""The catalogue is what the entry points say: the built-ins come from this project's
own ``activedesign.tasks`` and ``activedesign.learners`` entry points, and a plugin that
does not load is named with its reason instead of breaking the others.

Broken plugins are real distributions (a dist-info folder with ``entry_points.txt``, as
pip writes it) on the PYTHONPATH of a fresh interpreter, found by importlib.metadata."""

from __future__ import annotations

import json
import subprocess
import sys
from importlib.metadata import distribution
from pathlib import Path
from typing import Any

import pytest
from pydantic import ValidationError

from adclient.plugins import (
    LEARNER_GROUP,
    TASK_GROUP,
    LearnerSpec,
    PluginError,
    SimulatorOptions,
    TaskSpec,
    catalogue,
    load_object,
)
from adclient.schemas import NewTaskConfig

OWN = distribution("activedesign").entry_points
BUILT_IN_TASKS = {point.name for point in OWN.select(group=TASK_GROUP)}
BUILT_IN_LEARNERS = {point.name for point in OWN.select(group=LEARNER_GROUP)}


def test_the_built_ins_are_this_distributions_entry_points() -> None:
    assert {"stand-up", "diagonal-gesture", "lift-highest"} <= BUILT_IN_TASKS
    assert {"fast", "ddpg", "td3", "sac", "ppo"} <= BUILT_IN_LEARNERS
    installed = catalogue()
    assert set(installed.tasks) == BUILT_IN_TASKS and set(installed.learners) == BUILT_IN_LEARNERS
    assert installed.broken == {}
    for name, spec in installed.tasks.items():
        assert isinstance(spec, TaskSpec) and spec.name == name
        assert isinstance(spec.factory, str), "only the worker may import an environment"
    tunable = {name for name, spec in installed.learners.items() if spec.options is not None}
    assert tunable == BUILT_IN_LEARNERS - {"fast"}


def test_a_task_options_model_must_extend_task_options() -> None:
    with pytest.raises(TypeError, match="TaskOptions subclass"):
        TaskSpec(name="x", options=dict, description="", factory="x:y")  # type: ignore[arg-type]


def test_import_strings_say_which_part_is_missing() -> None:
    assert load_object("adclient.plugins:TaskSpec.load_factory") is TaskSpec.load_factory
    with pytest.raises(ValueError, match="module:attr"):
        load_object("adclient.plugins.TaskSpec")
    with pytest.raises(ImportError, match="has no 'Nope'"):
        load_object("adclient.plugins:Nope")
    with pytest.raises(ModuleNotFoundError):
        load_object("adclient.nope:x")


def test_study_tasks_are_checked_against_the_catalogue() -> None:
    with pytest.raises(ValidationError) as refused:
        NewTaskConfig(name="juggle")
    message = str(refused.value)
    assert "unknown task 'juggle'" in message
    assert ", ".join(sorted(BUILT_IN_TASKS)) in message
    assert "external: true" in message
    assert NewTaskConfig(name="juggle", learner="mine", external=True).name == "juggle"
    fast = {"learner_kwargs": {"learning_rate": 0.1}}
    with pytest.raises(ValidationError, match="learner 'fast' takes none"):
        NewTaskConfig(name="stand-up", learner="fast", options=fast)
    assert NewTaskConfig(name="stand-up", learner="sac", options=fast).learner == "sac"


def test_each_default_is_the_options_models() -> None:
    options = catalogue().tasks["stand-up"].options()
    assert (options.lifted_link, options.feet_links) == ("b", ["a", "c"])
    assert isinstance(options, SimulatorOptions) and options.frame_skip == 12


PLUGINS = {
    "good": """
from adclient.plugins import LearnerSpec, SimulatorOptions, TaskSpec
GOOD = TaskSpec(name="good", options=SimulatorOptions, description="d", factory="good:make")
MISNAMED = TaskSpec(name="other", options=SimulatorOptions, description="d", factory="good:x")
NOT_A_SPEC = {"name": "wrong"}
SLOW = LearnerSpec(name="slow", description="d", factory="good:learner")
""",
    "needs_mujoco": "import mujoco_that_is_not_installed\n",
}
ENTRY_POINTS = """
[activedesign.tasks]
good = good:GOOD
misnamed = good:MISNAMED
wrong = good:NOT_A_SPEC
juggle = needs_mujoco:JUGGLE
stand-up = good:GOOD

[activedesign.learners]
slow = good:SLOW
"""


def _catalogue_with_plugins(site: Path, code: str) -> Any:
    result = subprocess.run(
        [sys.executable, "-c", code],
        env={"PYTHONPATH": str(site), "PATH": "/usr/bin:/bin"},
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(result.stdout)


@pytest.fixture
def plugin_site(tmp_path: Path) -> Path:
    """A folder holding two modules and the dist-info of the distribution declaring them."""
    for module, source in PLUGINS.items():
        (tmp_path / f"{module}.py").write_text(source)
    info = tmp_path / "brokenplugins-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: brokenplugins\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(ENTRY_POINTS)
    return tmp_path


def test_broken_plugins_are_named_with_their_reason_and_the_rest_load(plugin_site: Path) -> None:
    code = (
        "import json\n"
        "from adclient.plugins import catalogue\n"
        "c = catalogue()\n"
        "print(json.dumps({'tasks': sorted(c.tasks), 'learners': sorted(c.learners),"
        " 'broken': dict(c.broken)}))\n"
    )
    found = _catalogue_with_plugins(plugin_site, code)
    assert found["tasks"] == sorted(BUILT_IN_TASKS - {"stand-up"} | {"good"})
    assert found["learners"] == sorted([*BUILT_IN_LEARNERS, "slow"])
    broken = found["broken"]
    assert set(broken) == {
        "activedesign.tasks:misnamed",
        "activedesign.tasks:wrong",
        "activedesign.tasks:juggle",
        "activedesign.tasks:stand-up",
    }
    assert "declares the name 'other', not 'misnamed'" in broken["activedesign.tasks:misnamed"]
    assert "is a dict, not a TaskSpec" in broken["activedesign.tasks:wrong"]
    juggle = broken["activedesign.tasks:juggle"]
    assert "brokenplugins 1.0 (needs_mujoco:JUGGLE)" in juggle
    assert "ModuleNotFoundError" in juggle and "mujoco_that_is_not_installed" in juggle
    duplicate = broken["activedesign.tasks:stand-up"]
    assert "declared more than once" in duplicate
    assert "activedesign 0.1.0" in duplicate and "brokenplugins 1.0" in duplicate


def test_a_study_naming_a_broken_task_says_why_it_does_not_load(plugin_site: Path) -> None:
    code = (
        "import json\n"
        "from pydantic import ValidationError\n"
        "from adclient.schemas import NewTaskConfig\n"
        "try:\n"
        "    NewTaskConfig(name='juggle')\n"
        "except ValidationError as error:\n"
        "    print(json.dumps(error.errors()[0]['msg']))\n"
    )
    message = _catalogue_with_plugins(plugin_site, code)
    assert "task 'juggle' is installed but does not load" in message
    assert "mujoco_that_is_not_installed" in message


def test_a_missing_task_is_a_plugin_error_listing_the_installed_ones() -> None:
    with pytest.raises(
        PluginError, match="the installed learners are ddpg, fast, mpc, ppo, ppo-batch, sac, td3"
    ):
        catalogue().learner("dreamer")
    assert isinstance(catalogue().learner("fast"), LearnerSpec)
