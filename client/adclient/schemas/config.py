"""What a study runs: its proposer and its task (as stored, and as a new study
checks them), and the installed tasks and learners they may name."""

from __future__ import annotations

from typing import Any, Literal, get_args, get_origin

from pydantic import (
    BaseModel,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from adclient.plugins import SIMULATORS, PluginError, catalogue, learner_budget_problems
from adclient.schemas.common import (
    NAME_PATTERN,
    JsonObject,
    StoredJsonObject,
    plain_text,
)
from adclient.strict import StrictInput, validate_strictly


class ProposerConfig(StrictInput):
    """Which proposer suggests new vectors, and how it starts."""

    name: str = Field(default="qei", pattern=NAME_PATTERN)
    n_initial: int = Field(default=2, ge=1, le=1000)
    seed: int = Field(default=0, ge=0, le=2**31 - 1)
    noisy: bool | None = Field(
        default=None,
        description="Model observation noise (qLogNEI). Default: true for managed studies.",
    )
    options: StoredJsonObject = Field(default_factory=dict)

    @field_validator("options")
    @classmethod
    def _options_text(cls, options: dict[str, Any]) -> dict[str, Any]:
        return plain_text(options, "options")


class NewProposerConfig(ProposerConfig):
    """A new study's proposer: its options are bounded (:data:`JsonObject`)."""

    options: JsonObject = Field(default_factory=dict)


class Fidelity(StrictInput):
    """A study's fidelity (``task.fidelity``): how long each design trains, chosen per
    trial by the default proposer between ``min`` and ``max`` (the target fidelity, at
    which the study's best is reported), at a cost ``fixed_cost + steps ** cost_exponent``
    in steps' worth of worker CPU (docs/method.md, multi-fidelity studies)."""

    param: Literal["train_steps"] = Field(
        default="train_steps", description="what the fidelity sets: the learner's train_steps"
    )
    min: int = Field(ge=1, le=10_000_000, description="the lowest fidelity a trial trains to")
    max: int = Field(
        ge=2,
        le=10_000_000,
        description="the target fidelity: the study's best is the best trial trained to it",
    )
    levels: int = Field(
        default=4,
        ge=2,
        le=16,
        description="how many fidelities the proposer chooses among, geometric from min to max",
    )
    cost_exponent: float = Field(
        default=1.0, ge=0.25, le=3.0, description="a trial's cost grows as steps ** this"
    )
    fixed_cost: int = Field(
        default=0,
        ge=0,
        le=10_000_000,
        description="steps' worth of cost every trial pays whatever its fidelity (building "
        "the robot, evaluating it)",
    )

    @model_validator(mode="after")
    def _range(self) -> Fidelity:
        if self.min >= self.max:
            raise ValueError(f"fidelity min {self.min} must be below max {self.max}")
        return self

    def grid(self) -> list[int]:
        """The fidelities trials train to, lowest first, geometric from min to max."""
        ratio = (self.max / self.min) ** (1.0 / (self.levels - 1))
        steps = [round(self.min * ratio**level) for level in range(self.levels - 1)]
        return sorted({*steps, self.max})

    def cost(self, steps: float) -> float:
        """A trial's cost at ``steps`` (steps' worth of worker CPU)."""
        return float(self.fixed_cost + steps**self.cost_exponent)


class TaskConfig(StrictInput):
    """What a worker does with a design: the task, the learner and their budgets.

    This is the form a study keeps and a job carries. A new study gives its task as
    :class:`NewTaskConfig`, which checks more; studies stored before those checks still
    load through this one (a mistake in them fails each trial in the worker)."""

    external: bool = Field(
        default=False,
        description="Run by workers of your own (SDK lease/tell), not adworker: the name, "
        "learner and options are theirs, unchecked, and any space is allowed",
    )
    name: str = Field(pattern=NAME_PATTERN)
    learner: str = Field(default="fast", pattern=NAME_PATTERN)
    simulator: str = Field(
        default=SIMULATORS[0],
        pattern=NAME_PATTERN,
        description="the physics engine the worker builds the task's world on: "
        f"{' or '.join(SIMULATORS)} (docs/worker.md, choosing the engine); the task must "
        "declare it (GET /api/v1/tasks, simulators)",
    )
    train_steps: int | None = Field(default=None, ge=0, le=10_000_000)
    eval_episodes: int = Field(default=3, ge=1, le=100)
    episode_steps: int | None = Field(default=None, ge=1, le=100_000)
    seed: int = Field(default=0, ge=0, le=2**31 - 1)
    options: StoredJsonObject = Field(default_factory=dict)
    transfer: Literal["none", "nearest", "shared"] = Field(
        default="none",
        description="nearest: a design starts its controller from the checkpoint of the "
        "nearest of the study's best evaluated designs of the same tree and trains "
        "transfer_steps; shared: one controller for the whole study, whose weights fit "
        "every tree, that each design starts from, trains transfer_steps and updates "
        "(docs/worker.md); none: every design trains from scratch",
    )
    transfer_steps: int | None = Field(
        default=None,
        ge=1,
        le=10_000_000,
        description="steps a warm-started design trains (default: a quarter of train_steps, "
        "or of the learner's own budget)",
    )
    shared_carries: Literal["critic", "all"] = Field(
        default="all",
        description="what a design of a shared study (transfer: shared) takes from the "
        "study's controller: all, actor and critic; critic, its critic, the actor "
        "starting from the study's initial weights (docs/worker.md, what a design carries)",
    )
    transfer_among: int = Field(
        default=4,
        ge=1,
        le=1000,
        description="the source is the nearest of this many best evaluated designs of the tree",
    )
    fidelity: Fidelity | None = Field(
        default=None,
        description="train each design to a fidelity the proposer chooses (its train_steps "
        "between min and max), the best reported at max (docs/study-file.md, fidelity); "
        "None: every design trains train_steps",
    )

    @field_validator("options")
    @classmethod
    def _options_text(cls, options: dict[str, Any]) -> dict[str, Any]:
        return plain_text(options, "options")

    def warm_steps(self, default_steps: int) -> int:
        """Steps a warm-started design trains: ``transfer_steps``, else a quarter of the
        from-scratch budget (``train_steps``, else the learner's ``default_steps``)."""
        if self.transfer_steps is not None:
            return self.transfer_steps
        budget = self.train_steps if self.train_steps is not None else default_steps
        return max(1, budget // 4)

    def at_fidelity(self, steps: int | None) -> TaskConfig:
        """The task a trial of a study with a ``fidelity`` runs, as its job carries it:
        train_steps its fidelity, else (a trial the proposer did not choose one for, an
        enqueued one) the target fidelity, and no fidelity (a worker needs only the
        steps, so a worker older than ``fidelity`` runs the job); the task itself
        without a fidelity."""
        if self.fidelity is None:
            return self
        steps = steps or self.fidelity.max
        return self.model_copy(update={"train_steps": steps, "fidelity": None})


def option_problems(
    error: ValidationError, model: type[BaseModel], owner: str, prefix: str = ""
) -> list[str]:
    """An options model's errors, each naming its option (after ``prefix``); an unknown
    key lists the options ``owner`` has. Shared by task options here and the service's
    check of proposer options."""
    known = ", ".join(model.model_fields) or "none"
    problems = []
    for item in error.errors():
        message = str(item["msg"]).removeprefix("Value error, ")
        loc = item["loc"]
        if item["type"] == "extra_forbidden":
            message = f"unknown option of {owner} (its options: {known})"
        elif item["type"] == "missing" and _tuple_item(model, loc, item.get("input")):
            # `target.2: Field required` for a 2-number target: say what the tuple takes
            loc, given = loc[:1], len(item["input"])
            message = f"expected {_tuple_item(model, loc, item['input'])} items, got {given}"
        where = ".".join([*filter(None, [prefix]), *(str(part) for part in loc)])
        if f"{where}: {message}" not in problems:  # one line for a tuple short of several
            problems.append(f"{where}: {message}")
    return problems


def _tuple_item(model: type[BaseModel], loc: tuple[Any, ...], given: Any) -> int:
    """The length of the fixed-length tuple option ``loc[0]`` when ``loc`` is one of its
    items and ``given`` the list it came as; 0 otherwise."""
    field = model.model_fields.get(str(loc[0])) if loc else None
    if field is None or not isinstance(given, list) or len(loc) > 2:
        return 0
    for annotation in (field.annotation, *get_args(field.annotation)):
        items = get_args(annotation)
        if get_origin(annotation) is tuple and items and Ellipsis not in items:
            return len(items)
    return 0


class NewTaskConfig(TaskConfig):
    """A new study's task: an installed task and learner (:mod:`adclient.plugins`) and
    options their models accept, unless the task is ``external``."""

    episode_steps: int | None = Field(default=None, ge=2, le=100_000)
    options: JsonObject = Field(default_factory=dict)

    @field_validator("name")
    @classmethod
    def _installed_task(cls, name: str, info: ValidationInfo) -> str:
        if not info.data.get("external"):
            try:
                catalogue().task(name)
            except PluginError as error:
                raise ValueError(
                    f"{error} (a task that workers of your own serve, such as adworker "
                    "--function, needs external: true)"
                ) from None
        return name

    @field_validator("learner")
    @classmethod
    def _installed_learner(cls, learner: str, info: ValidationInfo) -> str:
        if not info.data.get("external"):
            try:
                catalogue().learner(learner)
            except PluginError as error:
                raise ValueError(str(error)) from None
        return learner

    @field_validator("simulator")
    @classmethod
    def _known_simulator(cls, simulator: str, info: ValidationInfo) -> str:
        if simulator not in SIMULATORS:
            raise ValueError(
                f"{simulator!r} is not a simulator (simulators: {', '.join(SIMULATORS)})"
            )
        name = info.data.get("name")
        spec = None
        if isinstance(name, str) and not info.data.get("external"):
            spec = catalogue().tasks.get(name)
        if spec is not None and simulator not in spec.simulators:
            raise ValueError(
                f"task {spec.name!r} does not run on {simulator!r} (its simulators: "
                f"{', '.join(spec.simulators)})"
            )
        return simulator

    @model_validator(mode="after")
    def _learner_simulator(self) -> NewTaskConfig:
        """A learner that runs on some engines only (``LearnerSpec.simulators``: mpc on
        MuJoCo) on one of them, the default engine included."""
        spec = None if self.external else catalogue().learners.get(self.learner)
        engines = None if spec is None else spec.simulators
        if engines is not None and self.simulator not in engines:
            raise ValueError(
                f"learner {self.learner!r} does not run on simulator {self.simulator!r} "
                f"(its simulators: {', '.join(engines)}; task.simulator: {engines[0]})"
            )
        return self

    @field_validator("options")
    @classmethod
    def _known_options(cls, options: dict[str, Any], info: ValidationInfo) -> dict[str, Any]:
        plain_text(options, "options", finite=True)
        task, learner = str(info.data.get("name")), str(info.data.get("learner"))
        installed = catalogue()
        if info.data.get("external") or task not in installed.tasks:
            return options  # the task's own, or the name's error says what is wrong
        model = installed.tasks[task].options
        try:
            parsed = validate_strictly(model, options)
        except ValidationError as error:
            raise ValueError("; ".join(option_problems(error, model, f"task {task!r}"))) from None
        spec = installed.learners.get(learner)
        if parsed.learner_kwargs is None or spec is None:
            return options
        if spec.options is None:
            takes = [name for name, other in installed.learners.items() if other.options]
            raise ValueError(
                f"learner_kwargs: learner {learner!r} takes none (only {', '.join(takes)} do)"
            )
        try:
            validate_strictly(spec.options, parsed.learner_kwargs)
        except ValidationError as error:
            problems = option_problems(
                error, spec.options, f"learner {learner!r}", prefix="learner_kwargs"
            )
            raise ValueError("; ".join(problems)) from None
        return options

    @model_validator(mode="after")
    def _learner_budget(self) -> NewTaskConfig:
        """A learner's options within what it allows for this study's steps together
        (gradient updates for ``train_steps``...: ``LearnerOptions.budget_problems``)."""
        spec = None if self.external else catalogue().learners.get(self.learner)
        if spec is None or spec.options is None:
            return self
        kwargs = self.options.get("learner_kwargs") or {}
        options = validate_strictly(spec.options, kwargs)  # checked with the options
        problems = learner_budget_problems(options, self.train_steps, self.transfer_steps)
        if problems:
            owner = f"learner {self.learner!r}"
            raise ValueError("; ".join(f"options.learner_kwargs: {p} ({owner})" for p in problems))
        return self

    @model_validator(mode="after")
    def _fidelity_fits(self) -> NewTaskConfig:
        """A fidelity its learner can train to: one with a step budget, whose options
        allow the top fidelity's steps, training from scratch, ``train_steps`` (if given)
        the top fidelity."""
        fidelity = self.fidelity
        if fidelity is None or self.external:
            return self
        spec = catalogue().learners.get(self.learner)
        if spec is None or getattr(spec.options, "default_steps", None) is None:
            takes = [
                name
                for name, other in catalogue().learners.items()
                if getattr(other.options, "default_steps", None) is not None
            ]
            raise ValueError(
                f"task.fidelity: learner {self.learner!r} has no training steps to choose "
                f"(learners that have: {', '.join(takes)})"
            )
        if self.train_steps is not None and self.train_steps != fidelity.max:
            raise ValueError(
                f"task.fidelity: train_steps {self.train_steps} is not the top fidelity "
                f"(max {fidelity.max}): leave train_steps out or make it max"
            )
        if self.transfer != "none":
            raise ValueError(
                f"task.fidelity with transfer {self.transfer!r}: a warm-started design "
                "trains transfer_steps, not its fidelity; use transfer none"
            )
        assert spec.options is not None
        options = validate_strictly(spec.options, self.options.get("learner_kwargs") or {})
        problems = learner_budget_problems(options, fidelity.max)
        if problems:
            owner = f"learner {self.learner!r}"
            raise ValueError(
                "; ".join(f"task.fidelity.max {fidelity.max}: {p} ({owner})" for p in problems)
            )
        return self

    @field_validator("transfer")
    @classmethod
    def _learner_transfers(cls, transfer: str, info: ValidationInfo) -> str:
        learner = catalogue().learners.get(str(info.data.get("learner")))
        external = info.data.get("external")
        if external or learner is None:
            return transfer
        if transfer == "nearest" and not learner.transfers:
            takes = [name for name, spec in catalogue().learners.items() if spec.transfers]
            raise ValueError(
                f"learner {learner.name!r} cannot start from another design's controller "
                f"(transfer: none; learners that can: {', '.join(takes)})"
            )
        if transfer == "shared" and not learner.shares:
            takes = [name for name, spec in catalogue().learners.items() if spec.shares]
            raise ValueError(
                f"learner {learner.name!r} cannot train a controller shared by the study's "
                f"designs (transfer: none or nearest; learners that can: {', '.join(takes)})"
            )
        return transfer

    def links_looked_up(self) -> list[tuple[str, str]]:
        """(option, link name) for each link an installed task looks up in the robot."""
        if self.external:
            return []
        return catalogue().task(self.name).options.model_validate(self.options).link_names()


class TaskInfo(BaseModel):
    """An installed task (``GET /api/v1/tasks``): what a study's ``task.name`` may be."""

    name: str
    description: str
    options_schema: dict[str, Any] = Field(description="JSON schema of its task.options")
    fixed_base: bool = Field(
        default=False,
        description="its robot's root is fixed where the URDF puts it; false: the robot is "
        "free, set down on the ground",
    )
    templates: bool = Field(
        default=False,
        description="it builds its robot from the URDF alone: template studies may use it",
    )
    simulators: list[str] = Field(
        default_factory=lambda: [SIMULATORS[0]],
        description="the engines a study may name for it (task.simulator), the default "
        f"{SIMULATORS[0]} among them",
    )


class LearnerInfo(BaseModel):
    """An installed learner (``GET /api/v1/learners``)."""

    name: str
    description: str
    options_schema: dict[str, Any] | None = Field(
        description="JSON schema of task.options.learner_kwargs; null: it takes none"
    )
    simulators: list[str] = Field(
        default_factory=lambda: list(SIMULATORS),
        description="the engines a study may name for it (task.simulator): every one, or "
        "those it declares (mpc: mujoco)",
    )
