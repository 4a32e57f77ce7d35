"""The catalogue of tasks and learners: declarations that plugins install through entry points.

A task is a :class:`TaskSpec`: its name, a pydantic options model (the one place its
option defaults live), a description, and the factory of its environment. A learner is
a :class:`LearnerSpec` of the same shape. Packages declare them under the entry point
groups ``activedesign.tasks`` and ``activedesign.learners``, the built-in ones included
(see pyproject.toml)::

    [project.entry-points."activedesign.tasks"]
    reach = "my_robot_tasks:REACH"          # a TaskSpec, named "reach"

Loading the catalogue imports only the modules that hold the declarations, so they must
stay light: the server reads them to check study files without PyBullet or torch. A
factory is given as an import string (``"module:attr"``) that only the worker resolves
(:meth:`TaskSpec.load_factory`), or as a callable where importing it is cheap.
"""

from __future__ import annotations

import functools
import importlib
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from importlib.metadata import EntryPoint, entry_points
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

TASK_GROUP = "activedesign.tasks"
LEARNER_GROUP = "activedesign.learners"
SIMULATORS = ("pybullet", "mujoco")
"""The physics engines a study may name (``task.simulator``); the first is the default."""


class PluginError(LookupError):
    """A task or learner that is not installed, or whose plugin does not load."""


class TaskOptions(BaseModel):
    """``task.options`` every task understands; a task's own options model extends it.

    Validated when a study is created; the study keeps the mapping as given, and the
    worker hands the environment factory the validated model, defaults filled in."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    episode_steps: int | None = Field(default=None, ge=2, le=100_000)
    learner_kwargs: dict[str, Any] | None = Field(
        default=None,
        description="Options of the learner, checked with the learner's own options model "
        "(refused for a learner that declares none)",
    )

    def link_names(self) -> list[tuple[str, str]]:
        """(option, link name) for each link the task will look up in the robot: a study
        whose structures lack one is refused at creation."""
        return []


ScaleRange = tuple[
    Annotated[float, Field(ge=0.1, le=10.0)], Annotated[float, Field(ge=0.1, le=10.0)]
]
"""A [low, high] range of mass scales, each 0.1 to 10."""
FrictionRange = tuple[
    Annotated[float, Field(ge=0.0, le=5.0)], Annotated[float, Field(ge=0.0, le=5.0)]
]
"""A [low, high] range of friction coefficients, each 0 to 5."""
StrengthRange = tuple[
    Annotated[float, Field(ge=0.1, le=2.0)], Annotated[float, Field(ge=0.1, le=2.0)]
]
"""A [low, high] range of motor-strength scales, each 0.1 to 2."""


class SimulatorOptions(TaskOptions):
    """The options of a task on adworker's simulator (PyBullet, or MuJoCo where a study
    names it: ``task.simulator``): physics settings, the same on either engine."""

    frame_skip: int = Field(default=12, ge=1, le=1000, description="Physics steps per action")
    time_step: float = Field(default=1.0 / 120.0, gt=0.0, le=1.0, description="Physics step (s)")
    init_noise: float = Field(
        default=0.05,
        ge=0.0,
        le=math.pi,
        description="Largest random offset of each joint at the start of an episode (rad)",
    )
    rolling_friction: float = Field(
        default=0.02, ge=0.0, le=1000.0, description="Rolling friction of the links (m)"
    )
    spinning_friction: float = Field(
        default=0.0, ge=0.0, le=1000.0, description="Spinning friction of the links"
    )
    control: Literal["position", "torque"] = Field(
        default="position",
        description="What an action commands: 'position', a target in each joint's range "
        "(its motor applies up to the joint's effort to reach it, at up to its velocity); "
        "'torque', each joint's torque (force) as a fraction of its effort, -1 to 1",
    )
    mass_scale: ScaleRange | None = Field(
        default=None,
        description="[low, high]: each evaluation and training episode scales each link's "
        "mass (and inertia) by its own factor drawn uniformly from it, seeded by the "
        "episode's seed; null: the URDF's masses",
    )
    friction: FrictionRange | None = Field(
        default=None,
        description="[low, high]: each episode's friction coefficient between the links and "
        "the ground, drawn uniformly from it (seeded); null: 1.0",
    )
    motor_strength: StrengthRange | None = Field(
        default=None,
        description="[low, high]: each episode scales each joint's effort (its motor's "
        "largest torque or force, in either control) by its own factor drawn uniformly "
        "from it (seeded); null: the URDF's efforts",
    )

    @field_validator("mass_scale", "friction", "motor_strength")
    @classmethod
    def _ordered(cls, value: tuple[float, float] | None) -> tuple[float, float] | None:
        if value is not None and value[0] > value[1]:
            raise ValueError(f"a range is [low, high]: low ({value[0]}) must be <= high")
        return value

    @property
    def randomises(self) -> bool:
        """Whether an episode draws any of its physics (mass, friction, strength)."""
        return any(v is not None for v in (self.mass_scale, self.friction, self.motor_strength))


class LearnerOptions(BaseModel):
    """The base of a learner's options model (``LearnerSpec.options``): the whitelist of
    ``task.options.learner_kwargs``. Unknown options are refused by name, numbers must be
    finite, and each field's bounds are the plugin's to declare; what the options cost
    together for a job's steps is :meth:`budget_problems`. Checked when a study is
    created, and again by the worker for each job (a study stored before the check)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    def budget_problems(self, steps: int | None) -> list[str]:
        """Why a job training ``steps`` steps (None: the learner's own budget) with these
        options would cost more than the learner allows, each problem naming its options
        and the limit; none by default."""
        return []


def learner_budget_problems(
    options: BaseModel, train_steps: int | None, transfer_steps: int | None = None
) -> list[str]:
    """The budget problems of a learner's options for a study's ``train_steps`` and
    ``transfer_steps`` (a warm-started design's own budget), each once."""
    if not isinstance(options, LearnerOptions):
        return []
    problems = options.budget_problems(train_steps)
    if transfer_steps is not None:
        problems += [p for p in options.budget_problems(transfer_steps) if p not in problems]
    return problems


Factory = str | Callable[..., Any]
"""An import string ``"module:attr"`` or the callable itself."""


def load_object(reference: str) -> Any:
    """The object an import string ``"package.module:attr.path"`` names; a ValueError or
    ImportError that says which part is missing."""
    module_name, colon, path = reference.partition(":")
    if not colon or not module_name or not path:
        raise ValueError(f"{reference!r} is not an import string of the form 'module:attr'")
    found: Any = importlib.import_module(module_name)
    for part in path.split("."):
        try:
            found = getattr(found, part)
        except AttributeError:
            raise ImportError(f"{reference!r}: module {module_name!r} has no {path!r}") from None
    return found


def _resolve(factory: Factory, what: str) -> Callable[..., Any]:
    found = load_object(factory) if isinstance(factory, str) else factory
    if not callable(found):
        raise TypeError(f"{what}: {factory!r} is not callable")
    return found


@dataclass(frozen=True)
class TaskSpec:
    """A task: what studies name, how its options are checked, and what builds its env.

    The worker calls the factory with keyword arguments ``design`` (the decoded
    :class:`~adclient.designs.Design`), ``urdf_path`` (where the worker wrote its URDF)
    and ``options`` (an instance of ``options``); it returns the task's environment
    (see docs/plugins.md for what the learners need of it)."""

    name: str
    options: type[TaskOptions]
    description: str
    factory: Factory = field(repr=False)
    templates: bool = False
    """It builds its robot from the URDF alone (``design=None``), so template studies
    may use it; a task that needs the decoded design leaves it False."""
    fixed_base: bool = False
    """Its robot's root is fixed where its URDF puts it; False: the robot is free, set
    down on the ground (``adclient.spawn``: where the server says the robot starts, so
    it must be what adworker's task class says, ``Task.fixed_base``)."""
    simulators: tuple[str, ...] = ("pybullet",)
    """The engines of :data:`SIMULATORS` a study may name for it (``task.simulator``).
    The worker passes the factory ``simulator=`` only for another engine than the
    default, so a factory that takes no such argument declares the default alone."""

    def __post_init__(self) -> None:
        if not (isinstance(self.options, type) and issubclass(self.options, TaskOptions)):
            raise TypeError(f"task {self.name!r}: options must be a TaskOptions subclass")
        unknown = [name for name in self.simulators if name not in SIMULATORS]
        if unknown or SIMULATORS[0] not in self.simulators:
            raise TypeError(
                f"task {self.name!r}: simulators must include {SIMULATORS[0]!r} and name "
                f"only engines of {', '.join(SIMULATORS)} (got {', '.join(self.simulators)})"
            )

    def load_factory(self) -> Callable[..., Any]:
        """The environment factory, imported now (the worker's side only)."""
        return _resolve(self.factory, f"task {self.name!r}")


@dataclass(frozen=True)
class LearnerSpec:
    """A learner: its name, the options model of ``task.options.learner_kwargs`` (None:
    it takes none; else a whitelist that refuses unknown options, best a
    :class:`LearnerOptions` with each option bounded), and the factory the worker calls
    with those options (a model instance, or None) to get an object with ``train(env,
    steps=, seed=, check=, start=, keep_checkpoint=, reporting=)`` (docs/plugins.md).

    ``transfers``: it takes part in a study's ``task.transfer`` (docs/worker.md): it
    trains on from a ``start=Warm(checkpoint, steps)`` (bytes of a checkpoint it
    returned), and returns its final state as ``TrainResult.checkpoint`` when asked
    (``keep_checkpoint``). Those bytes (and a promoted trial's ``Resume``) come from
    the server: a worker's
    upload, but still to be read as data only (``torch.load(weights_only=True)``,
    ``np.load(allow_pickle=False)``, JSON; never ``pickle`` or SB3's ``Model.load``),
    filling a model built from the job's own settings (docs/plugins.md).

    ``shares``: it takes part in ``task.transfer: shared``: it trains from a
    ``start=Shared(weights, steps, seed, version)`` (named float32 arrays that fit every
    design of the study, or None for the study's initial ones) and returns the weights
    it ends with as ``TrainResult.shared`` and those it started from as
    ``TrainResult.shared_start`` (docs/plugins.md)."""

    name: str
    description: str
    factory: Factory = field(repr=False)
    options: type[BaseModel] | None = None
    transfers: bool = False
    shares: bool = False
    simulators: tuple[str, ...] | None = None
    """The engines of :data:`SIMULATORS` it runs on (a study's ``task.simulator``);
    None: every one. A study naming another is refused at creation, naming both."""

    def __post_init__(self) -> None:
        if self.simulators is not None and not set(self.simulators) <= set(SIMULATORS):
            raise TypeError(
                f"learner {self.name!r}: simulators must name engines of "
                f"{', '.join(SIMULATORS)} (got {', '.join(self.simulators)})"
            )
        options = self.options
        if options is None:
            return
        if not (isinstance(options, type) and issubclass(options, BaseModel)):
            raise TypeError(f"learner {self.name!r}: options must be a pydantic model")
        if options.model_config.get("extra") != "forbid":
            raise TypeError(
                f"learner {self.name!r}: its options model {options.__name__} must refuse "
                "unknown options (extend adclient.plugins.LearnerOptions, or "
                "model_config = ConfigDict(extra='forbid'))"
            )

    def load_factory(self) -> Callable[..., Any]:
        return _resolve(self.factory, f"learner {self.name!r}")


@dataclass(frozen=True)
class Catalogue:
    """What is installed: tasks and learners by name, and why any plugin did not load."""

    tasks: Mapping[str, TaskSpec]
    learners: Mapping[str, LearnerSpec]
    broken: Mapping[str, str]
    """``"group:name"`` of each entry point that did not load: the reason."""

    def task(self, name: str) -> TaskSpec:
        return self._find(TASK_GROUP, self.tasks, name, "task")  # type: ignore[return-value]

    def learner(self, name: str) -> LearnerSpec:
        return self._find(LEARNER_GROUP, self.learners, name, "learner")  # type: ignore[return-value]

    def describe(
        self, problem: Callable[[TaskSpec | LearnerSpec], str | None] | None = None
    ) -> list[str]:
        """Lines listing the tasks, the learners and the broken plugins, for the CLIs;
        ``problem`` says why a spec cannot run here (None: it can)."""
        lines = []
        specs: tuple[tuple[str, Mapping[str, TaskSpec | LearnerSpec]], ...] = (
            ("tasks", self.tasks),
            ("learners", self.learners),
        )
        for kind, found in specs:
            lines.append(f"{kind}:")
            for name, spec in sorted(found.items()):
                why = problem(spec) if problem is not None else None
                state = f"  [does not load: {why}]" if why else ""
                lines.append(f"  {name:<18} {spec.description}{state}")
        lines += [f"broken plugin {key}: {reason}" for key, reason in sorted(self.broken.items())]
        return lines

    def _find(
        self, group: str, found: Mapping[str, TaskSpec | LearnerSpec], name: str, kind: str
    ) -> TaskSpec | LearnerSpec:
        if name in found:
            return found[name]
        reason = self.broken.get(f"{group}:{name}")
        if reason is not None:
            raise PluginError(f"{kind} {name!r} is installed but does not load: {reason}")
        raise PluginError(
            f"unknown {kind} {name!r}; the installed {kind}s are {', '.join(sorted(found))}"
        )


def _load_group(
    group: str, kind: type[TaskSpec] | type[LearnerSpec], broken: dict[str, str]
) -> dict[str, Any]:
    """Each entry point of ``group`` that loads to a ``kind`` named as its entry point;
    the others, and names two distributions both claim, go to ``broken``."""
    by_name: dict[str, list[EntryPoint]] = {}
    for point in entry_points(group=group):
        by_name.setdefault(point.name, []).append(point)
    loaded: dict[str, Any] = {}
    for name, points in sorted(by_name.items()):
        key = f"{group}:{name}"
        if len(points) > 1:
            owners = ", ".join(f"{_owner(point)} ({point.value})" for point in points)
            broken[key] = f"declared more than once: {owners}"
            continue
        (point,) = points
        where = f"{_owner(point)} ({point.value})"
        try:
            spec = point.load()
        except Exception as error:
            broken[key] = f"{where}: {type(error).__name__}: {error}"
            continue
        if not isinstance(spec, kind):
            broken[key] = f"{where}: is a {type(spec).__name__}, not a {kind.__name__}"
        elif spec.name != name:
            broken[key] = f"{where}: declares the name {spec.name!r}, not {name!r}"
        else:
            loaded[name] = spec
    return loaded


def _owner(point: EntryPoint) -> str:
    dist = point.dist
    return f"{dist.name} {dist.version}" if dist is not None else "unknown distribution"


@functools.cache
def catalogue() -> Catalogue:
    """The installed tasks and learners, read once per process."""
    broken: dict[str, str] = {}
    tasks = _load_group(TASK_GROUP, TaskSpec, broken)
    learners = _load_group(LEARNER_GROUP, LearnerSpec, broken)
    return Catalogue(tasks=tasks, learners=learners, broken=broken)


def installed_tasks() -> Mapping[str, TaskSpec]:
    return catalogue().tasks


def installed_learners() -> Mapping[str, LearnerSpec]:
    return catalogue().learners
