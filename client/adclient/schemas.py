"""The HTTP contract: every request and response body of the v1 API.

These pydantic models are the one source of truth shared by the server (which
validates and serialises with them) and by the SDK and workers (which parse with
them). Fields may be added; the paths, names and codes of v1 stay.
"""

from __future__ import annotations

import json
import math
import unicodedata
from datetime import datetime
from enum import StrEnum
from typing import Annotated, Any, Literal

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    GetJsonSchemaHandler,
    SerializerFunctionWrapHandler,
    Tag,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_serializer,
    model_validator,
)
from pydantic.json_schema import JsonSchemaValue
from pydantic_core import CoreSchema

from adclient.design import DesignSpace, Representation
from adclient.objectives import (
    MAX_CONSTRAINTS,
    MAX_OBJECTIVES,
    Constraint,
    Direction,
    Objective,
    Outcomes,
    outcomes_of,
)
from adclient.plugins import PluginError, catalogue
from adclient.pruning import Checkpoint, PrunerConfig

NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.\-]{0,127}$"
"""Names of studies, params, metrics and artifacts: safe in URLs, file names and XML."""
MAX_STUDY_NAME = 200
"""A study's name is free text for people (its id is the key in every URL and file)."""
NO_NUL_PATTERN = r"^[^\x00]*$"
"""Free text: anything but NUL, which PostgreSQL cannot store in a text column."""

MAX_ASK = 64
MAX_TRIAL_PAGE = 1000
"""The most trials one ``GET /studies/{id}/trials`` answers (also its default page); the
SDK pages through longer studies."""
MAX_JSON_DEPTH = 32
MAX_JSON_BYTES = 64 * 1024
"""Bounds of every free JSON field (study metadata, proposer and task options): deep
enough for any real configuration, far below what serialisers refuse (256 levels), and
small enough that a listing of many studies stays cheap."""


class StudyState(StrEnum):
    running = "running"
    complete = "complete"
    stopped = "stopped"


class TrialState(StrEnum):
    queued = "queued"
    running = "running"
    complete = "complete"
    failed = "failed"
    pruned = "pruned"
    paused = "paused"
    """Stopped at an ASHA rung with its checkpoint, waiting for promotion (queued again
    then) or the study's end (pruned then); not finished."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


def _plain_text(value: Any, where: str, *, finite: bool = False) -> Any:
    """Refuse strings that cannot be stored and sent back: NUL (PostgreSQL cannot store
    it) and lone surrogates (not encodable as UTF-8), anywhere in a JSON value. With
    ``finite``, refuse NaN and infinite numbers too (not JSON: PostgreSQL refuses them,
    answers drop them); new studies are checked so, while studies already stored keep
    loading."""
    if finite and isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"{where}: numbers must be finite, got {value!r}")
    if isinstance(value, str):
        if "\x00" in value:
            raise ValueError(f"{where}: text must not contain NUL")
        try:
            value.encode("utf-8")
        except UnicodeEncodeError:
            raise ValueError(f"{where}: text must be valid Unicode (no lone surrogates)") from None
    elif isinstance(value, dict):
        for key, item in value.items():
            _plain_text(key, f"{where} key")
            _plain_text(item, f"{where}.{key}", finite=finite)
    elif isinstance(value, list):
        for index, item in enumerate(value):
            _plain_text(item, f"{where}[{index}]", finite=finite)
    return value


def _finite(value: float, what: str) -> float:
    if not math.isfinite(value):
        raise ValueError(f"{what} must be a finite number, got {value!r}")
    return value


def _json_depth(value: Any, limit: int) -> int:
    """How deep objects and arrays nest in ``value``, counted no further than one past
    ``limit`` (without recursion: a hostile value must not exhaust the stack)."""
    deepest = 0
    stack = [(value, 1)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, dict):
            children = list(item.values())
        elif isinstance(item, list):
            children = item
        else:
            continue
        deepest = max(deepest, depth)
        if depth <= limit:
            stack.extend((child, depth + 1) for child in children)
    return deepest


def _bounded_json(value: dict[str, Any], limit: int = MAX_JSON_BYTES) -> dict[str, Any]:
    """Refuse a free JSON object nested deeper than ``MAX_JSON_DEPTH`` or larger than
    ``limit`` bytes encoded: stored, it would cost every listing, or fail to serialise."""
    if _json_depth(value, MAX_JSON_DEPTH) > MAX_JSON_DEPTH:
        raise ValueError(f"objects and arrays nest deeper than {MAX_JSON_DEPTH} levels")
    size = len(json.dumps(value, ensure_ascii=False, default=str).encode("utf-8", "surrogatepass"))
    if size > limit:
        raise ValueError(f"{size} bytes as JSON, more than the limit of {limit}")
    return value


_NAME_CONTROLS = frozenset("\u061c\u200e\u200f") | {chr(c) for c in range(0x202A, 0x202F)}
_NAME_CONTROLS |= {chr(c) for c in range(0x2066, 0x206A)}
"""Direction marks, embeddings, overrides and isolates: they reorder the text shown
around a name (a terminal line, a table row) without being seen."""


def study_name(name: str) -> str:
    """A study's name: any letters, digits, spaces and punctuation, but no control
    characters (they break lines in logs, tables and terminals, or reorder text unseen)
    and not only spaces (nothing to read)."""
    for index, char in enumerate(name):
        if unicodedata.category(char) in ("Cc", "Cs", "Zl", "Zp") or char in _NAME_CONTROLS:
            raise ValueError(
                f"a study name must not contain control characters: U+{ord(char):04X} "
                f"at position {index}"
            )
    if not name.strip():
        raise ValueError("a study name must not be blank")
    return name


StudyName = Annotated[
    str,
    Field(
        min_length=1,
        max_length=MAX_STUDY_NAME,
        description=f"free text of 1 to {MAX_STUDY_NAME} characters, no control characters",
    ),
    AfterValidator(study_name),
]


CUT_JSON = "(nested too deep)"
"""What an answer shows instead of nesting past ``MAX_JSON_DEPTH`` in a stored value."""


def _cut_json(value: Any, levels: int) -> Any:
    if isinstance(value, dict | list) and levels <= 0:
        return CUT_JSON
    if isinstance(value, dict):
        return {key: _cut_json(item, levels - 1) for key, item in value.items()}
    if isinstance(value, list):
        return [_cut_json(item, levels - 1) for item in value]
    return value


def _shown_json(value: dict[str, Any]) -> dict[str, Any]:
    """A stored free JSON object as answers carry it: nesting past ``MAX_JSON_DEPTH``
    (a row stored before the limit) is cut, so one such row cannot fail a listing."""
    if _json_depth(value, MAX_JSON_DEPTH) <= MAX_JSON_DEPTH:
        return value
    cut: dict[str, Any] = _cut_json(value, MAX_JSON_DEPTH)
    return cut


JsonObject = Annotated[
    dict[str, Any],
    AfterValidator(_bounded_json),
    Field(
        description=f"A JSON object: at most {MAX_JSON_DEPTH} levels deep and "
        f"{MAX_JSON_BYTES} bytes encoded"
    ),
]
"""Every free JSON field of a request: the one place its limits are checked."""
StoredJsonObject = Annotated[dict[str, Any], AfterValidator(_shown_json)]
"""The same fields in answers, which must serialise whatever an older server stored."""

MAX_USER_ATTRS_BYTES = 16 * 1024
"""The most one study's or trial's user attributes take as JSON, merged: every page of
trials carries its trials' attributes (a page of 1000 full ones is 16 MB)."""
MAX_USER_ATTR_KEY = 128


def bounded_user_attrs(attrs: dict[str, Any]) -> dict[str, Any]:
    """User attributes within the limits of every free JSON field (depth, plain text,
    finite numbers), keys of 1 to ``MAX_USER_ATTR_KEY`` characters, and at most
    ``MAX_USER_ATTRS_BYTES`` encoded: checked on a request and again once merged."""
    _plain_text(attrs, "user_attrs", finite=True)
    for key in attrs:
        if not 1 <= len(key) <= MAX_USER_ATTR_KEY:
            raise ValueError(
                f"user_attrs: key {key[:40]!r} must be 1 to {MAX_USER_ATTR_KEY} characters"
            )
    try:
        return _bounded_json(attrs, MAX_USER_ATTRS_BYTES)
    except ValueError as error:
        raise ValueError(f"user_attrs: {error}") from None


UserAttrs = Annotated[
    dict[str, Any],
    AfterValidator(bounded_user_attrs),
    Field(
        description="keys set to these values; a null value deletes its key (Optuna's "
        f"set_user_attr, many at once); at most {MAX_USER_ATTRS_BYTES} bytes merged"
    ),
]


Choice = Annotated[str | bool | int | float, Field(description="a choice")]
"""A categorical param's choice: text, a boolean or a number, kept exactly as given."""
_NUMERIC_FIELDS = ("low", "high", "log", "step")
MAX_CHOICES = 1000
MAX_STEPS = 1e15
"""The most grid steps of a stepped param: beyond, grid values are no longer exact."""


class BoxParam(_Strict):
    """One searched param: a float (``log`` scale and a ``step`` grid optional), an int
    (the same options) or a categorical one of ``choices``. Without ``type`` it is a
    float, which is all a box param was before types."""

    name: str = Field(pattern=NAME_PATTERN)
    type: Literal["float", "int", "categorical"] = "float"
    low: int | float | None = None
    high: int | float | None = None
    log: bool = Field(default=False, description="searched on a log scale (low > 0)")
    step: int | float | None = Field(
        default=None, description="values only on the grid low, low + step, ..., high"
    )
    choices: list[Choice] | None = Field(default=None, description="a categorical param's values")

    @model_validator(mode="after")
    def _check_bounds(self) -> BoxParam:
        where = f"param {self.name!r}"
        for field, value in (("low", self.low), ("high", self.high), ("step", self.step)):
            if isinstance(value, int) and abs(value) > 2**53:
                raise ValueError(f"{where}: {field} must be within +-2**53 (exact as a float)")
        if self.type == "categorical":
            return self._check_choices(where)
        if self.choices is not None:
            raise ValueError(f"{where}: choices belong to a categorical param, not {self.type}")
        if self.low is None or self.high is None:
            missing = " and ".join(f for f in ("low", "high") if getattr(self, f) is None)
            article = "an" if self.type == "int" else "a"
            raise ValueError(f"{where}: {article} {self.type} param needs {missing}")
        _finite(self.low, f"{where}: low")
        _finite(self.high, f"{where}: high")
        if not self.low < self.high:
            raise ValueError(f"{where}: low ({self.low}) must be < high ({self.high})")
        if self.log and self.low <= 0:
            raise ValueError(f"{where}: a log scale needs low > 0, got {self.low}")
        if self.type == "int":
            for bound in ("low", "high", "step"):
                value = getattr(self, bound)
                if value is not None and not float(value).is_integer():
                    raise ValueError(
                        f"{where}: an int param's {bound} must be an integer, got {value}"
                    )
                if value is not None:
                    setattr(self, bound, int(value))
        if self.step is not None:
            self._check_step(where)
        return self

    def _check_step(self, where: str) -> None:
        assert self.step is not None and self.low is not None and self.high is not None
        _finite(self.step, f"{where}: step")
        if self.step <= 0:
            raise ValueError(f"{where}: step must be > 0, got {self.step}")
        if self.log:
            raise ValueError(f"{where}: step and log do not go together (a grid is linear)")
        intervals = (self.high - self.low) / self.step
        if not intervals <= MAX_STEPS:
            raise ValueError(f"{where}: step ({self.step}) makes more than {MAX_STEPS:g} steps")
        if abs(intervals - round(intervals)) > 1e-9 * max(1.0, intervals) or round(intervals) < 1:
            raise ValueError(
                f"{where}: step ({self.step}) does not divide the range "
                f"[{self.low}, {self.high}] into whole steps"
            )

    def _check_choices(self, where: str) -> BoxParam:
        given = [name for name in _NUMERIC_FIELDS if name in self.model_fields_set]
        if given and (given != ["log"] or self.log):
            verb = "does" if len(given) == 1 else "do"
            raise ValueError(f"{where}: {', '.join(given)} {verb} not apply to a categorical param")
        if not self.choices:
            raise ValueError(f"{where}: a categorical param needs a non-empty list of choices")
        if len(self.choices) > MAX_CHOICES:
            raise ValueError(f"{where}: at most {MAX_CHOICES} choices, got {len(self.choices)}")
        kinds = {
            "text" if isinstance(c, str) else "boolean" if isinstance(c, bool) else "number"
            for c in self.choices
        }
        if len(kinds) > 1:
            raise ValueError(
                f"{where}: choices must all be of one type, got {' and '.join(sorted(kinds))}"
            )
        for choice in self.choices:
            if isinstance(choice, float):
                _finite(choice, f"{where}: choice")
            if isinstance(choice, int) and not isinstance(choice, bool) and abs(choice) > 2**53:
                raise ValueError(f"{where}: a number choice must be within +-2**53")
        seen: list[Any] = []
        for choice in self.choices:
            if choice in seen:
                raise ValueError(f"{where}: choice {choice!r} appears twice")
            seen.append(choice)
        _plain_text(self.choices, f"{where}: choices")
        return self

    @model_serializer(mode="wrap")
    def _without_unset(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        """Fields that do not apply to the type are left out (no nulls in answers)."""
        data: dict[str, Any] = handler(self)
        if self.type == "categorical":
            data.pop("log", None)
        return {key: value for key, value in data.items() if value is not None}


class BoxSpace(_Strict):
    """A plain continuous box: each param searched between its bounds."""

    type: Literal["box"]
    params: list[BoxParam] = Field(min_length=1, max_length=256)

    @field_validator("params")
    @classmethod
    def _unique_names(cls, params: list[BoxParam]) -> list[BoxParam]:
        seen: set[str] = set()
        for param in params:
            if param.name in seen:
                raise ValueError(f"duplicate param name {param.name!r}")
            seen.add(param.name)
        return params


Space = Annotated[BoxSpace | DesignSpace, Field(discriminator="type")]


class ProposerConfig(_Strict):
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
        return _plain_text(options, "options")


class NewProposerConfig(ProposerConfig):
    """A new study's proposer: its options are bounded (:data:`JsonObject`)."""

    options: JsonObject = Field(default_factory=dict)


class TaskConfig(_Strict):
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
    train_steps: int | None = Field(default=None, ge=0, le=10_000_000)
    eval_episodes: int = Field(default=3, ge=1, le=100)
    episode_steps: int | None = Field(default=None, ge=1, le=100_000)
    seed: int = Field(default=0, ge=0, le=2**31 - 1)
    options: StoredJsonObject = Field(default_factory=dict)

    @field_validator("options")
    @classmethod
    def _options_text(cls, options: dict[str, Any]) -> dict[str, Any]:
        return _plain_text(options, "options")


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
        if item["type"] == "extra_forbidden":
            message = f"unknown option of {owner} (its options: {known})"
        where = ".".join([*filter(None, [prefix]), *(str(part) for part in item["loc"])])
        problems.append(f"{where}: {message}")
    return problems


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

    @field_validator("options")
    @classmethod
    def _known_options(cls, options: dict[str, Any], info: ValidationInfo) -> dict[str, Any]:
        _plain_text(options, "options", finite=True)
        task, learner = str(info.data.get("name")), str(info.data.get("learner"))
        installed = catalogue()
        if info.data.get("external") or task not in installed.tasks:
            return options  # the task's own, or the name's error says what is wrong
        model = installed.tasks[task].options
        try:
            parsed = model.model_validate(options)
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
            spec.options.model_validate(parsed.learner_kwargs)
        except ValidationError as error:
            problems = option_problems(
                error, spec.options, f"learner {learner!r}", prefix="learner_kwargs"
            )
            raise ValueError("; ".join(problems)) from None
        return options

    def links_looked_up(self) -> list[tuple[str, str]]:
        """(option, link name) for each link an installed task looks up in the robot."""
        if self.external:
            return []
        return catalogue().task(self.name).options.model_validate(self.options).link_names()


ObjectiveName = Annotated[str, Field(min_length=1, max_length=128, pattern=NO_NUL_PATTERN)]


class StudyCreate(_Strict):
    name: StudyName
    direction: Direction = Direction.maximize
    directions: list[Direction] | None = Field(
        default=None,
        min_length=1,
        max_length=MAX_OBJECTIVES,
        description="several objectives (a tell gives `values`, one per direction), "
        "instead of `direction`",
    )
    objective_names: list[ObjectiveName] | None = Field(
        default=None, description="a name per direction (default: value_0, value_1, ...)"
    )
    objectives: list[Objective] | None = Field(
        default=None,
        min_length=1,
        max_length=MAX_OBJECTIVES,
        description="objectives read from a tell's value (`value` or `score`) and metrics "
        "(a managed study's task metrics, such as `mass`), instead of `direction(s)`",
    )
    constraints: list[Constraint] = Field(
        default_factory=list,
        min_length=0,
        max_length=MAX_CONSTRAINTS,
        description="outcome constraints on told metrics (or objectives by name): a trial "
        "that breaks one is complete but infeasible",
    )
    reference_point: list[Annotated[float, Field(allow_inf_nan=False)]] | None = Field(
        default=None,
        description="the hypervolume reference point of a study of several objectives, in "
        "the objectives' own units (default: inferred from the trials)",
    )
    space: Space
    proposer: NewProposerConfig = Field(default_factory=NewProposerConfig)
    pruner: PrunerConfig = Field(default_factory=PrunerConfig)
    task: NewTaskConfig | None = None
    max_trials: int | None = Field(default=None, ge=1, le=1_000_000)
    max_attempts: int = Field(default=3, ge=1, le=100)
    metadata: JsonObject = Field(default_factory=dict)

    @field_validator("metadata")
    @classmethod
    def _metadata_text(cls, metadata: dict[str, Any]) -> dict[str, Any]:
        return _plain_text(metadata, "metadata", finite=True)

    @field_validator("proposer", "task", mode="before")
    @classmethod
    def _checked_as_new(cls, value: Any) -> Any:
        """A ``ProposerConfig`` or ``TaskConfig`` built in Python is checked as a new
        study's (``NewProposerConfig``, ``NewTaskConfig``)."""
        if isinstance(value, ProposerConfig | TaskConfig):
            return value.model_dump(exclude_unset=True)
        return value

    @field_validator("proposer")
    @classmethod
    def _proposer_numbers(cls, proposer: ProposerConfig) -> ProposerConfig:
        _plain_text(proposer.options, "options", finite=True)
        return proposer

    @field_validator("space")
    @classmethod
    def _searchable_widths(cls, space: BoxSpace | DesignSpace) -> BoxSpace | DesignSpace:
        """Each searched range's width must be a number too (high - low of two huge
        bounds overflows, and every proposed value would then be the upper bound)."""
        if isinstance(space, BoxSpace):
            ranges = [
                (f"param {p.name!r}", p.low, p.high)
                for p in space.params
                if p.low is not None and p.high is not None
            ]
        else:
            names, bounds = space.spec_slots()
            ranges = [
                (f"spec {name!r}", low, high)
                for name, (low, high) in zip(names, bounds, strict=True)
            ]
        for what, low, high in ranges:
            if not math.isfinite(high - low):
                raise ValueError(
                    f"{what}: the width high - low ({high} - {low}) overflows; "
                    "choose bounds closer together"
                )
        return space

    @model_validator(mode="after")
    def _objectives(self) -> StudyCreate:
        if self.directions is not None and self.objectives is not None:
            raise ValueError("directions and objectives: give one of them")
        outcomes = self.outcomes()
        first = outcomes.directions[0]
        if "direction" in self.model_fields_set and self.direction != first:
            several = "directions" if self.directions is not None else "objectives"
            raise ValueError(
                f"direction ({self.direction.value}) and {several} (first: {first.value}) "
                f"disagree: give one of direction and {several}"
            )
        if self.objective_names is not None:
            if self.directions is None:
                raise ValueError("objective_names: name the objectives of `directions`")
            if len(self.objective_names) != len(self.directions):
                raise ValueError(
                    f"objective_names: {len(self.objective_names)} names for "
                    f"{len(self.directions)} directions"
                )
        if len(set(outcomes.names)) != outcomes.count:
            raise ValueError(f"objectives: each objective needs its own name, got {outcomes.names}")
        if self.reference_point is not None:
            if not outcomes.multi:
                raise ValueError("reference_point: only a study of several objectives has one")
            if len(self.reference_point) != outcomes.count:
                raise ValueError(
                    f"reference_point: {len(self.reference_point)} numbers for "
                    f"{outcomes.count} objectives"
                )
        if outcomes.multi and self.pruner.name != "none":
            raise ValueError(
                f"pruner: {self.pruner.name!r} ranks trials by one value; a study of several "
                "objectives takes pruner none"
            )
        return self

    def outcomes(self) -> Outcomes:
        """The study's objectives and constraints, as tells are checked against them."""
        return outcomes_of(
            direction=self.direction,
            directions=self.directions,
            objective_names=self.objective_names,
            objectives=self.objectives,
            constraints=self.constraints,
            reference_point=self.reference_point,
        )

    @model_validator(mode="after")
    def _managed_study(self) -> StudyCreate:
        if self.task is None:
            return self
        if self.max_trials is None:
            raise ValueError("max_trials is required for a study with a task (a managed study)")
        if self.task.external:
            return self
        if not isinstance(self.space, DesignSpace):
            raise ValueError(
                f"task {self.task.name!r} builds a robot: it needs a design space "
                f"(space.type: design), not {self.space.type!r}"
            )
        for option, link in self.task.links_looked_up():
            missing = [
                index
                for index, edges in enumerate(self.space.tree_structures())
                if link not in {name for edge in edges for name in edge}
            ]
            if missing:
                raise ValueError(
                    f"task {self.task.name!r} looks up link {link!r} (task.options.{option}), "
                    f"but structures[{missing[0]}] has no link of that name; name the "
                    f"instances accordingly or set task.options.{option}"
                )
        return self


class Study(BaseModel):
    id: int
    name: str
    direction: Direction = Field(description="the first objective's direction")
    directions: list[Direction] = Field(
        default_factory=list, description="one per objective (empty in answers of old servers)"
    )
    objective_names: list[str] = Field(default_factory=list)
    objectives: list[Objective] | None = Field(
        default=None, description="where each objective is read from in a tell, if not `values`"
    )
    constraints: list[Constraint] = Field(default_factory=list)
    reference_point: list[float] | None = None
    state: StudyState
    managed: bool
    space: Space
    proposer: ProposerConfig
    pruner: PrunerConfig = Field(default_factory=PrunerConfig)
    task: TaskConfig | None
    max_trials: int | None
    max_attempts: int
    n_trials: int
    n_queued: int
    n_running: int
    n_complete: int
    n_failed: int
    n_pruned: int = 0
    n_paused: int = 0
    best_value: float | None
    best_trial_id: int | None
    metadata: StoredJsonObject
    user_attrs: StoredJsonObject = Field(
        default_factory=dict, description="set with PATCH /studies/{id}"
    )
    created_by: str | None = Field(
        default=None, description="the name of the token that created the study (auth on)"
    )
    created_at: datetime
    updated_at: datetime


class TrialCurve(BaseModel):
    """One trial's reported curve, as the dashboard draws a study's learning curves."""

    trial_id: int
    number: int
    state: TrialState
    steps: list[int]
    values: list[float]


class StudyCurves(BaseModel):
    """The reported curves of a study's latest trials that reported, oldest first
    (``GET /api/v1/dashboard/studies/{id}/curves``)."""

    curves: list[TrialCurve]
    more: bool = Field(description="earlier trials reported too and are left out")


class TrialColumns(BaseModel):
    """A page of a study's trials as parallel columns, in order of number: the small
    payload charts draw from (``GET /studies/{id}/series``)."""

    number: list[int]
    state: list[TrialState]
    value: list[float | None]
    params: dict[str, list[float | str | bool | None]] = Field(
        description="each param that has a number (or, for a box's categorical param, a "
        "choice) in some trial of the page: its values (null where a trial has none)"
    )
    values: list[list[float] | None] | None = Field(
        default=None,
        description="a study of several objectives: each trial's objective values (null "
        "where it has none); null for a study of one objective",
    )
    feasible: list[bool | None] | None = Field(
        default=None,
        description="a study with constraints: whether each trial meets them (null where it "
        "has no outcome); null for a study without constraints",
    )
    next: int | None = Field(
        default=None,
        description="more trials follow: ask again with `after` set to this; null at the end",
    )


class AskRequest(_Strict):
    count: int = Field(default=1, ge=1, le=MAX_ASK)


class Trial(BaseModel):
    id: int
    study_id: int
    number: int
    state: TrialState
    params: dict[str, Any]
    vector: list[float]
    value: float | None
    values: list[float] | None = Field(
        default=None, description="a study of several objectives: one value per objective"
    )
    feasible: bool | None = Field(
        default=None,
        description="whether a finished trial meets the study's constraints (null: the "
        "study has none, or the trial has no outcome)",
    )
    message: str | None = None
    metrics: dict[str, float] = Field(default_factory=dict)
    info: dict[str, Any] = Field(default_factory=dict, description="Proposer's notes")
    worker_id: str | None
    attempts: int = 0
    created_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None
    heartbeat_at: datetime | None = None
    lease_expires_at: datetime | None = None
    checkpoint: Checkpoint | None = Field(
        default=None, description="where a paused (or promoted) trial resumes from"
    )
    user_attrs: StoredJsonObject = Field(
        default_factory=dict, description="set with PATCH /trials/{id}"
    )


class StudyUpdate(_Strict):
    """``PATCH /studies/{id}``: its user attributes, merged into those it has."""

    user_attrs: UserAttrs


class TrialUpdate(StudyUpdate):
    """``PATCH /trials/{id}``: as :class:`StudyUpdate`; a worker setting attributes on
    the trial it runs (Optuna's objective calling ``trial.set_user_attr``) names itself
    in ``worker_id``, as it does to tell."""

    worker_id: str | None = Field(
        default=None, min_length=1, max_length=128, pattern=NO_NUL_PATTERN
    )


class AskResponse(BaseModel):
    trials: list[Trial]


class TellRequest(_Strict):
    """``{"value": v}`` completes a trial; ``{"state": "failed", "message": m}`` fails it;
    ``{"state": "pruned"}`` (optionally with its last ``value``) ends it early, as its
    study's pruner asked.

    The published JSON schema says exactly that (one of two shapes), so generated
    clients and fuzzers see the same rule the validator enforces."""

    value: float | None = None
    values: list[float] | None = Field(default=None, min_length=1, max_length=MAX_OBJECTIVES)
    state: Literal["complete", "failed", "pruned"] = "complete"
    message: str | None = Field(default=None, max_length=10_000, pattern=NO_NUL_PATTERN)
    worker_id: str | None = Field(
        default=None, min_length=1, max_length=128, pattern=NO_NUL_PATTERN
    )
    metrics: dict[str, float] = Field(default_factory=dict, max_length=256)

    @model_validator(mode="after")
    def _consistent(self) -> TellRequest:
        if self.values is not None:
            _outcome_values(self.values, self.value, self.state)
            if len(self.values) == 1:  # one objective told as a list
                self.value, self.values = self.values[0], None
        elif self.state == "complete":
            if self.value is None:
                raise ValueError(
                    "value is required to complete a trial (values: several objectives)"
                )
            _finite(self.value, "value")
        elif self.state == "pruned":
            if self.value is not None:
                _finite(self.value, "value")
        elif self.value is not None:
            raise ValueError("a failed trial carries no value")
        for key, metric in self.metrics.items():
            _finite(metric, f"metric {key!r}")
        _plain_text(self.metrics, "metrics")
        _plain_text(self.message, "message")
        return self

    @classmethod
    def __get_pydantic_json_schema__(
        cls, core_schema: CoreSchema, handler: GetJsonSchemaHandler
    ) -> JsonSchemaValue:
        schema = handler.resolve_ref_schema(handler(core_schema))
        common = {k: v for k, v in schema["properties"].items() if k not in ("value", "state")}
        complete = {
            "type": "object",
            "title": "TellComplete",
            "properties": {
                "value": {"type": "number"},
                "values": {
                    "type": "array",
                    "items": {"type": "number"},
                    "minItems": 1,
                    "maxItems": MAX_OBJECTIVES,
                    "description": "a study of several objectives: one number per objective",
                },
                "state": {"const": "complete", "default": "complete"},
                **common,
            },
            "oneOf": [{"required": ["value"]}, {"required": ["values"]}],
            "additionalProperties": False,
        }
        failed = {
            "type": "object",
            "title": "TellFailed",
            "properties": {"state": {"const": "failed"}, **common},
            "required": ["state"],
            "additionalProperties": False,
        }
        pruned = {
            "type": "object",
            "title": "TellPruned",
            "properties": {"state": {"const": "pruned"}, "value": {"type": "number"}, **common},
            "required": ["state"],
            "additionalProperties": False,
        }
        return {
            "title": "TellRequest",
            "description": cls.__doc__,
            "oneOf": [complete, failed, pruned],
        }


def _outcome_values(values: list[float], value: float | None, state: str) -> None:
    """``values`` of a tell or a handed-over trial: finite, instead of ``value``, and only
    for a complete trial."""
    if value is not None:
        raise ValueError("give value or values, not both")
    if state != "complete":
        raise ValueError(f"a {state} trial carries no values")
    for index, item in enumerate(values):
        _finite(item, f"values[{index}]")


MAX_TRIALS_ADDED = 10_000
"""Trials one ``POST /studies/{id}/trials`` may add."""


class TrialAdd(_Strict):
    """A trial handed to a study (``POST /studies/{id}/trials``).

    Without an outcome it is *enqueued*: a ``queued`` trial of these params, handed out
    before any proposal by the next ask (or leased by a worker, for a managed study),
    as Optuna's ``enqueue_trial``. With ``value`` (or ``state: failed``) it is an
    evaluation the user already has, stored finished and seen by the proposer (a warm
    start, as Optuna's ``add_trial``). ``params`` are checked against the study's space
    and stored as the study's own params (for a design space, the design they encode)."""

    params: JsonObject
    state: Literal["queued", "complete", "failed", "pruned"] | None = Field(
        default=None,
        description="default: complete with a value, queued without one",
    )
    value: float | None = None
    values: list[float] | None = Field(default=None, min_length=1, max_length=MAX_OBJECTIVES)
    message: str | None = Field(default=None, max_length=10_000, pattern=NO_NUL_PATTERN)
    metrics: dict[str, float] = Field(default_factory=dict, max_length=256)
    skip_if_exists: bool = Field(
        default=False,
        description="a trial of the same params already queued, running or finished "
        "(failed ones aside) is answered in place of a new one",
    )

    @model_validator(mode="after")
    def _consistent(self) -> TrialAdd:
        if self.state is None:
            told = self.value is not None or self.values is not None
            self.state = "complete" if told else "queued"
        if self.values is not None:
            _outcome_values(self.values, self.value, self.state)
            if len(self.values) == 1:
                self.value, self.values = self.values[0], None
        if self.state == "complete" and self.value is None and self.values is None:
            raise ValueError("value is required for a complete trial (values: several objectives)")
        if self.state in ("queued", "failed") and self.value is not None:
            raise ValueError(f"a {self.state} trial carries no value")
        if self.value is not None:
            _finite(self.value, "value")
        if self.state == "queued" and (self.metrics or self.message is not None):
            raise ValueError("a queued trial carries no metrics or message")
        for key, metric in self.metrics.items():
            _finite(metric, f"metric {key!r}")
        _plain_text(self.metrics, "metrics")
        _plain_text(self.message, "message")
        return self


TrialAdds = Annotated[list[TrialAdd], Field(min_length=1, max_length=MAX_TRIALS_ADDED)]
TrialAddBody = Annotated[
    Annotated[TrialAdd, Tag("trial")] | Annotated[TrialAdds, Tag("trials")],
    Discriminator(lambda body: "trials" if isinstance(body, list) else "trial"),
]
"""One trial (an object) or several (a list); an error names ``trial.<field>`` or
``trials.<index>.<field>``."""


class LeaseRequest(_Strict):
    worker_id: str = Field(min_length=1, max_length=128, pattern=NO_NUL_PATTERN)
    tasks: list[Annotated[str, Field(pattern=NAME_PATTERN)]] | None = Field(
        default=None,
        max_length=256,
        description="lease only trials of studies whose task has one of these names "
        "(the tasks this worker can run); none: any task",
    )


class HeartbeatRequest(_Strict):
    worker_id: str = Field(min_length=1, max_length=128, pattern=NO_NUL_PATTERN)


class ReleaseRequest(_Strict):
    """The lease holder giving a trial back to the queue (``POST /trials/{id}/release``);
    an admin may name no worker, to take back a trial whatever holds it."""

    worker_id: str | None = Field(
        default=None, min_length=1, max_length=128, pattern=NO_NUL_PATTERN
    )


class HeartbeatResponse(BaseModel):
    trial_id: int
    lease_expires_at: datetime


class Job(BaseModel):
    """Everything a stateless worker needs to evaluate one trial."""

    trial_id: int
    study_id: int
    number: int
    attempt: int
    vector: list[float]
    params: dict[str, Any]
    task: TaskConfig
    space: Space
    representation: Representation | None
    lease_expires_at: datetime
    pruner: PrunerConfig = Field(
        default_factory=PrunerConfig,
        description="the study's pruner: with one, adworker evaluates and reports while "
        "it trains (every pruner.report_every steps) and stops when told",
    )
    resume: Checkpoint | None = Field(
        default=None,
        description="a promoted trial: download this checkpoint artifact and train on from "
        "its step to the budget instead of starting over",
    )


class TaskInfo(BaseModel):
    """An installed task (``GET /api/v1/tasks``): what a study's ``task.name`` may be."""

    name: str
    description: str
    options_schema: dict[str, Any] = Field(description="JSON schema of its task.options")


class LearnerInfo(BaseModel):
    """An installed learner (``GET /api/v1/learners``)."""

    name: str
    description: str
    options_schema: dict[str, Any] | None = Field(
        description="JSON schema of task.options.learner_kwargs; null: it takes none"
    )


class ArtifactInfo(BaseModel):
    name: str
    size: int
    content_type: str
    created_at: datetime


class WorkerInfo(BaseModel):
    worker_id: str
    last_seen_at: datetime
    current_trial_id: int | None
    jobs_done: int
    jobs_failed: int


class SignInRequest(_Strict):
    """The dashboard's sign-in: the token is sent once and never stored by the page."""

    token: str = Field(min_length=1, max_length=256, pattern=NO_NUL_PATTERN)


class SessionInfo(BaseModel):
    """Who the caller is (``GET /api/v1/session``): what the dashboard shows and needs."""

    auth: bool = Field(description="whether the server requires a token")
    signed_in: bool
    role: str | None = None
    name: str | None = None
    csrf_token: str | None = Field(
        default=None,
        description="with a sign-in cookie, send this in X-CSRF-Token on every change",
    )


class ErrorBody(BaseModel):
    """Every 4xx/5xx answer: a machine-readable code and a message naming what is wrong."""

    error: str
    detail: Any
    problems: list[str] | None = Field(default=None, description="each invalid field, named")
