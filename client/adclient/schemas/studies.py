"""Studies: the body that creates one, a study as answers carry it, and the update
of its user attributes."""

from __future__ import annotations

import math
import statistics
from datetime import datetime
from typing import Annotated, Any

from pydantic import (
    BaseModel,
    Field,
    field_validator,
    model_validator,
)

from adclient.design import DesignSpace
from adclient.objectives import (
    MAX_CONSTRAINTS,
    MAX_OBJECTIVES,
    Constraint,
    Direction,
    DirectionName,
    Objective,
    Outcomes,
    outcomes_of,
)
from adclient.pruning import PrunerConfig
from adclient.schemas.common import (
    NO_NUL_PATTERN,
    JsonObject,
    StoredJsonObject,
    StudyName,
    StudyState,
    UserAttrs,
    plain_text,
)
from adclient.schemas.config import NewProposerConfig, NewTaskConfig, ProposerConfig, TaskConfig
from adclient.schemas.space import BoxSpace, Space, TemplateSpace
from adclient.strict import StrictInput

ObjectiveName = Annotated[str, Field(min_length=1, max_length=128, pattern=NO_NUL_PATTERN)]

ONE_DESIGN_REPEATS = 5
"""``max_trials`` of a study of one design (a space that searches nothing) left unset."""


class StudyCreate(StrictInput):
    name: StudyName
    direction: DirectionName = Direction.maximize
    directions: list[DirectionName] | None = Field(
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
        return plain_text(metadata, "metadata", finite=True)

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
        plain_text(proposer.options, "options", finite=True)
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
        if self.space.searches_nothing:
            self._one_design()
        if self.task is None:
            return self
        if self.max_trials is None:
            raise ValueError("max_trials is required for a study with a task (a managed study)")
        if self.task.transfer == "shared" and self.pruner.options.get("promotion"):
            raise ValueError(
                "task.transfer: shared with pruner.options.promotion: a paused design would "
                "resume outside the study's shared controller; use promotion false or "
                "transfer nearest"
            )
        if self.task.fidelity is not None:
            self._fidelity_study()
        if self.task.external:
            return self
        if isinstance(self.space, TemplateSpace):
            return self  # its links are known once expanded: the server checks them
        if not isinstance(self.space, DesignSpace):
            raise ValueError(
                f"task {self.task.name!r} builds a robot: it needs a design space "
                f"(space.type: design) or a template (space.type: template), "
                f"not {self.space.type!r}"
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

    def _fidelity_study(self) -> None:
        """A fidelity is chosen by the default proposer (qei), and replaces a pruner:
        each trial trains to the fidelity it carries, whole."""
        if self.proposer.name != "qei":
            raise ValueError(
                f"task.fidelity: proposer {self.proposer.name!r} does not choose fidelities; "
                "use proposer qei (the default), or leave task.fidelity out"
            )
        several = len(self.directions or []) > 1 or len(self.objectives or []) > 1
        if several or self.constraints:
            raise ValueError(
                "task.fidelity: a multi-fidelity study has one objective and no "
                "constraints; leave task.fidelity out for objectives or constraints"
            )
        if self.pruner.name != "none":
            raise ValueError(
                f"task.fidelity with pruner {self.pruner.name!r}: the proposer chooses how "
                "long each design trains; use pruner none"
            )

    def _one_design(self) -> None:
        """A space that searches nothing is one design, evaluated ``max_trials`` times
        (``ONE_DESIGN_REPEATS`` unset), each repeat on its own seed: independent
        repeats, so nothing that carries one repeat into another (a pruner stopping
        some by the others, a controller transferred from another)."""
        if self.max_trials is None:
            self.max_trials = ONE_DESIGN_REPEATS
        if self.pruner.name != "none":
            raise ValueError(
                f"pruner: {self.pruner.name!r} stops trials by the others' values, but the "
                "space searches nothing: each trial repeats its one design, and the spread "
                "of the repeats needs them all; use pruner none"
            )
        if self.task is not None and self.task.transfer != "none":
            raise ValueError(
                f"task.transfer: {self.task.transfer!r} starts a trial from another's "
                "controller, but the space searches nothing: each trial repeats its one "
                "design from scratch on its own seed; use transfer none"
            )


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
    searched_params: list[str] | None = Field(
        default=None,
        description="the keys of its trials' params that the study searches: a box's or "
        "template's every param; a design study's free specs, catalogue choices, free "
        "axes and, of several structures, the structure (adclient.decode.searched_params), "
        "the rest being fixed by its study file or following from these (ties, mirrors, "
        "catalogues). Null in answers of old servers",
    )
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
    proposal_error: str | None = Field(
        default=None,
        description="why the study's last proposal failed (its exception's type and "
        "message); null once one succeeds",
    )
    proposal_failures: int = Field(
        default=0, description="proposals of the study that failed in a row (0: none)"
    )
    proposal_retry_at: datetime | None = Field(
        default=None,
        description="after failed proposals, workers' leases skip the study until this "
        "time (UTC); the wait doubles with each failure, up to AD_PROPOSAL_BACKOFF_MAX_SECONDS",
    )
    proposal_fallbacks: int = Field(
        default=0,
        description="candidates that were Sobol points because a time or memory budget "
        "or a failed model stopped the proposer (their trials' info says degraded: true)",
    )
    proposal_fallback_reason: str | None = Field(
        default=None,
        description="why the latest model-based ask fell back to Sobol points; null when "
        "it did not",
    )
    fixed: bool = Field(
        default=False,
        description="the space searches nothing: every trial repeats its one design on "
        "its own seed, and GET /studies/{id}/spread gives the spread of the values",
    )


class ObjectiveSpread(BaseModel):
    """How one objective's values spread over a study's complete trials."""

    name: str
    n: int = Field(description="complete trials with a value")
    mean: float | None
    std: float | None = Field(description="sample standard deviation (n - 1); null below 2")
    min: float | None
    median: float | None
    max: float | None

    @classmethod
    def of(cls, name: str, values: list[float]) -> ObjectiveSpread:
        """The spread of ``values`` (finite numbers); every number null for none, and a
        mean, std or median past the float range null (two values of 1e308 have no
        finite mean). They are computed on the values divided by a power of two, which
        is exact, so a sum on the way does not overflow (it raised OverflowError)."""
        if not values:
            return cls(name=name, n=0, mean=None, std=None, min=None, median=None, max=None)
        exponent = math.frexp(max(abs(v) for v in values))[1]
        unit = [math.ldexp(v, -exponent) for v in values]

        def scaled_back(number: float) -> float | None:
            try:
                return math.ldexp(number, exponent)
            except OverflowError:
                return None

        return cls(
            name=name,
            n=len(values),
            mean=scaled_back(statistics.fmean(unit)),
            std=scaled_back(statistics.stdev(unit)) if len(values) > 1 else None,
            min=min(values),
            median=scaled_back(statistics.median(unit)),
            max=max(values),
        )


class StudySpread(BaseModel):
    """``GET /studies/{id}/spread``: each objective's spread over the study's complete
    trials (feasible or not). For a study of one design (``Study.fixed``) that is the
    spread of its repeats, what such a study is for."""

    study_id: int
    fixed: bool
    objectives: list[ObjectiveSpread]


class StudyUpdate(StrictInput):
    """``PATCH /studies/{id}``: its user attributes, merged into those it has."""

    user_attrs: UserAttrs
