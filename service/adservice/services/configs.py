"""A study's configuration (space, proposer, representation) never changes after it is
created, so each server process keeps it parsed in memory (:class:`StudyConfigs`)."""

from __future__ import annotations

import logging
import math
import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pydantic import ValidationError

from adclient.boxspace import BoxEncoding
from adclient.design import DesignSpace
from adclient.designs import Representation
from adclient.errors import quoted
from adclient.objectives import Outcomes, stored_outcomes
from adclient.polytope import SpecPolytope, broken_spec_constraints, spec_polytope
from adclient.pruning import PrunerConfig
from adclient.schemas import ProposerConfig, TaskConfig, option_problems
from adclient.strict import validate_strictly
from adservice.db import Database
from adservice.errors import InvalidError
from adservice.models import StudyRow
from adservice.proposers import available, options_model
from adservice.proposers.base import SearchStructure
from adservice.repository import studies as study_repo

log = logging.getLogger("adservice")


def check_proposer(config: ProposerConfig, *, stored: bool = False) -> None:
    """A known proposer and options it declares; InvalidError naming each problem. A new
    study's options take a body's strict types; ``stored`` ones are read as the options
    model reads them (an older server let lax values in, and those studies must ask)."""
    if config.name not in available():
        raise InvalidError(
            f"proposer.name: unknown proposer {config.name!r}; "
            f"choose one of {', '.join(available())}"
        )
    model = options_model(config.name)
    try:
        if stored:
            model.model_validate(config.options)
        else:
            validate_strictly(model, config.options)
    except ValidationError as error:
        problems = option_problems(error, model, config.name, prefix="proposer.options")
        raise InvalidError("; ".join(problems), problems=problems) from None


@dataclass(frozen=True)
class StudyConfig:
    """The immutable part of a study, parsed once."""

    study_id: int
    maximize: bool
    owner_token_id: int | None
    owner_name: str | None
    proposer: ProposerConfig
    task: TaskConfig | None
    space: dict[str, Any]
    design_space: DesignSpace | None
    representation: Representation | None
    bounds: np.ndarray
    search: SearchStructure | None = None
    polytope: SpecPolytope | None = None
    """A design space's spec constraints over its search vectors (None: none)."""
    """What a design vector's coordinates mean, for proposers that model them."""
    box: BoxEncoding | None = None
    """A box of typed params (int, log, step, categorical): how its vectors encode them.
    None for a design space and for a box of plain floats (vector = params)."""
    proposer_error: InvalidError | None = None
    """Why the stored proposer settings cannot be used (a study stored before they were
    checked at creation): asking such a study answers 409 naming the problem."""
    pruner: PrunerConfig = field(default_factory=PrunerConfig)
    """The study's pruner; ``pruner.pruned_as`` says how its proposer sees pruned trials."""
    outcomes: Outcomes = field(default_factory=Outcomes)
    """Its objectives and constraints."""

    @classmethod
    def from_row(cls, row: StudyRow) -> StudyConfig:
        proposer = ProposerConfig.model_validate(row.proposer)
        try:
            check_proposer(proposer, stored=True)
            proposer_error = None
        except InvalidError as error:
            proposer_error = error
            log.warning("study %d cannot propose: %s", row.id, error.detail)
        representation: Representation | None = None
        design_space: DesignSpace | None = None
        search: SearchStructure | None = None
        polytope: SpecPolytope | None = None
        box: BoxEncoding | None = None
        if row.representation is not None:
            from adservice.representation import search_structure

            representation = Representation.model_validate(row.representation)
            bounds = np.asarray(representation.bounds, dtype=np.float64)
            design_space = DesignSpace.model_validate(row.space)
            search = search_structure(design_space, representation)
            polytope = spec_polytope(design_space, representation)
        else:
            box = BoxEncoding.of(row.space)
            bounds = box.bounds
            box = box if box.typed else None
        return cls(
            study_id=row.id,
            maximize=row.direction == "maximize",
            owner_token_id=row.owner_token_id,
            owner_name=row.created_by,
            proposer=proposer,
            task=TaskConfig.model_validate(row.task) if row.task else None,
            space=row.space,
            design_space=design_space,
            representation=representation,
            bounds=bounds,
            search=search,
            polytope=polytope,
            box=box,
            proposer_error=proposer_error,
            pruner=PrunerConfig.model_validate(row.pruner or {}),
            outcomes=stored_outcomes(row.outcomes, direction=row.direction),
        )

    @property
    def dim(self) -> int:
        return int(self.bounds.shape[1])

    @property
    def fixed(self) -> bool:
        """Whether the space searches nothing (a zero-length search vector): every trial
        repeats its one design, and no proposer runs."""
        return self.dim == 0

    def repeat_seed(self, number: int) -> int:
        """The seed of trial ``number`` of a study of one design: the study's seed (its
        task's, else its proposer's) plus the number, so each repeat trains and evaluates
        on its own seed and a trial run again reproduces itself."""
        base = self.task.seed if self.task is not None else self.proposer.seed
        return (base + number) % 2**31

    def canonical(self, candidates: np.ndarray) -> np.ndarray:
        """Proposed vectors as stored: in the box, typed params snapped to their values,
        a catalogue choice's coordinates those of the component it picks (so the model
        sees each component at one point, as it sees a categorical's choices)."""
        if self.box is not None:
            return self.box.snap(candidates)
        clipped = np.clip(candidates, self.bounds[0], self.bounds[1])
        if self.design_space is None or not self.design_space.catalogues:
            return clipped
        assert self.representation is not None
        if self.representation.kind == "fused":  # encode is approximate there
            return clipped
        from adclient.decode import decode
        from adclient.encode import encode

        return np.array(
            [
                encode(
                    self.design_space,
                    self.representation,
                    decode(self.design_space, self.representation, row.tolist()),
                )
                for row in clipped
            ]
        )

    def params(self, vector: np.ndarray) -> dict[str, Any]:
        """What a person reads: box params by name in their types, or the decoded design."""
        if self.box is not None:
            return self.box.decode(vector)
        if self.representation is None or self.design_space is None:
            names = [p["name"] for p in self.space["params"]]
            return {name: float(x) for name, x in zip(names, vector, strict=True)}
        from adclient.decode import decode, design_params

        return design_params(decode(self.design_space, self.representation, vector.tolist()))

    def given(self, params: dict[str, Any], vector: np.ndarray) -> dict[str, Any]:
        """Params a user hands over (checked by :meth:`vector`, whose result ``vector``
        is) as their trial keeps them: box params exactly as given, a design's (and the one
        design's of a space that searches nothing) as decoded (its specs round-trip
        exactly already)."""
        if self.fixed or (self.representation is not None and self.design_space is not None):
            return self.params(vector)
        return (self.box or BoxEncoding.of(self.space)).given(params)

    def vector(self, params: dict[str, Any]) -> np.ndarray:
        """The inverse of :meth:`params`, for params a user hands over: ValueError naming a
        missing, unknown, out-of-range or mistyped param. A design's params are its specs
        (``structure_index`` picks the structure; a ``structure``, ``root``, shape, joint
        kind or, but for a fused representation, joint axis given must be the design's,
        as the params it shows: they are derived, not read). A study of one design takes
        only that design: no params, or its own."""
        if self.fixed:
            return self._one_design(params)
        if self.representation is None or self.design_space is None:
            return (self.box or BoxEncoding.of(self.space)).encode(params)
        from adclient.decode import decode, design_params
        from adclient.encode import encode

        try:
            vector = np.asarray(encode(self.design_space, self.representation, params))
        except (TypeError, ValueError) as error:
            raise ValueError(str(error).removeprefix("encode: ")) from None
        design = decode(self.design_space, self.representation, vector.tolist())
        broken = broken_spec_constraints(self.design_space, design)
        if broken:
            raise ValueError(f"the design breaks {'; '.join(broken)}")
        shown = design_params(design)
        if "structure" in params and params["structure"] != shown["structure"]:
            raise ValueError(
                f"structure {params['structure']!r} is not structure_index "
                f"{params.get('structure_index', 0)} ({shown['structure']!r})"
            )
        # derived, not read; a fused vector's axis angles are the nearest, not the same
        derived = (
            ".shape",
            ".joint.kind",
            *((".joint.axis",) if self.representation.kind != "fused" else ()),
        )
        for key, value in params.items():
            checked = key in shown and (key == "root" or key.endswith(derived))
            if checked and not _same_value(value, shown[key]):
                raise ValueError(
                    f"{key} = {quoted(value)} is not this design's: its specs give "
                    f"{shown[key]!r}; leave {key!r} out or give that value"
                )
        return vector

    def _one_design(self, params: dict[str, Any]) -> np.ndarray:
        """The vector of a study of one design (zero-length) for params that name no other
        design: each one given is one of the design's params with its value."""
        own = self.params(np.zeros(0))
        for key, value in params.items():
            if key not in own:
                known = f"its params: {', '.join(own)}" if own else "it has no params"
                raise ValueError(
                    f"{key!r} is no param of the study's one design ({known}); the space "
                    "searches nothing, so give {} or the design's own params"
                )
            if not _same_value(value, own[key]):
                raise ValueError(
                    f"{key} = {value!r} is not the study's one design, whose {key} is "
                    f"{own[key]!r}: the space searches nothing, so give {{}} or its own params"
                )
        return np.zeros(0)


def _same_value(given: Any, own: Any) -> bool:
    """A value as a user gives it back (numbers to 1e-9 relative, lists item by item)."""
    if isinstance(own, list):
        return (
            isinstance(given, list)
            and len(given) == len(own)
            and all(_same_value(a, b) for a, b in zip(given, own, strict=True))
        )
    if isinstance(own, bool) or isinstance(given, bool):
        return given is own
    if isinstance(own, int | float):
        return isinstance(given, int | float) and math.isclose(
            given, own, rel_tol=1e-9, abs_tol=1e-12
        )
    return bool(given == own)


class StudyConfigs:
    """Each study's parsed configuration, read from the database once per process."""

    def __init__(self, db: Database) -> None:
        self._db = db
        self._lock = threading.Lock()
        self._configs: dict[int, StudyConfig] = {}

    def cached(self, study_id: int) -> StudyConfig | None:
        """The configuration if this process has it already (no database read)."""
        return self._configs.get(study_id)

    def cached_outcomes(self, study_id: int) -> Outcomes | None:
        """A study's objectives and constraints if this process has its configuration
        (a tell reads the row otherwise, in its own transaction)."""
        config = self._configs.get(study_id)
        return config.outcomes if config is not None else None

    def get(self, study_id: int) -> StudyConfig:
        config = self._configs.get(study_id)
        if config is None:
            with self._db.read() as session:
                config = StudyConfig.from_row(study_repo.get_study(session, study_id=study_id))
            with self._lock:
                config = self._configs.setdefault(study_id, config)
        return config
