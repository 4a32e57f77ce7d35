"""docs/study-file.md cannot drift from the schema: its examples validate, its field
tables list exactly the models' fields with their defaults and ranges, and its error
example is what validation really answers."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Annotated, Any

import annotated_types
import pytest
import yaml
from pydantic import BaseModel, TypeAdapter, ValidationError

from adclient.design import DesignSpace
from adclient.parts import JointType, PartInstance, PartType
from adclient.plugins import SimulatorOptions, catalogue
from adclient.pruning import PrunerConfig
from adclient.schemas import (
    BoxParam,
    BoxSpace,
    NewTaskConfig,
    ProposerConfig,
    StudyCreate,
    TemplateSpace,
)
from adclient.spec_constraints import SpecConstraint
from adclient.specs import Bound
from adclient.templates import check_template

ROOT = Path(__file__).resolve().parents[2]
DOC = (ROOT / "docs" / "study-file.md").read_text(encoding="utf-8")

TABLES: dict[str, type[BaseModel]] = {
    "StudyCreate": StudyCreate,
    "BoxSpace": BoxSpace,
    "BoxParam": BoxParam,
    "TemplateSpace": TemplateSpace,
    "DesignSpace": DesignSpace,
    "PartType": PartType,
    "JointType": JointType,
    "PartInstance": PartInstance,
    "SpecConstraint": SpecConstraint,
    "ProposerConfig": ProposerConfig,
    "PrunerConfig": PrunerConfig,
    "NewTaskConfig": NewTaskConfig,
    "SimulatorOptions": SimulatorOptions,
}
"""Each model's field table follows a ``<!-- fields: Name -->`` marker in the doc."""


def _blocks(language: str) -> list[str]:
    return re.findall(rf"^```{language}\n(.*?)^```$", DOC, flags=re.MULTILINE | re.DOTALL)


def _table(model_name: str) -> dict[str, list[str]]:
    """Rows of the model's field table: field name -> [type, default, meaning] cells."""
    marker = f"<!-- fields: {model_name} -->\n"
    assert marker in DOC, f"no field table for {model_name}"
    lines = DOC.split(marker, 1)[1].splitlines()
    rows: dict[str, list[str]] = {}
    for line in lines[2:]:  # past the header and its rule
        if not line.startswith("|"):
            break
        cells = [cell.strip() for cell in line.strip().strip("|").split(" | ")]
        name = re.fullmatch(r"`([a-z_]+)`", cells[0])
        assert name, f"{model_name}: first cell is not a field name: {cells[0]!r}"
        assert len(cells) == 4, f"{model_name}.{name.group(1)}: expected 4 cells: {line!r}"
        rows[name.group(1)] = cells[1:]
    return rows


def _number(value: float) -> str:
    return str(value) if isinstance(value, int) else f"{value:g}"


def _range_texts(metadata: list[Any], unit: str = "items") -> list[str]:
    """How the doc writes a field's bounds: "N to M", or "≥ N", "> N", "≤ M"; lengths
    in ``unit`` (characters of text, items of a list)."""
    limits: dict[str, float] = {}
    for item in metadata:
        for kind in ("ge", "gt", "le", "lt", "min_length", "max_length"):
            value = getattr(item, kind, None)
            if isinstance(item, annotated_types.BaseMetadata) and value is not None:
                limits[kind] = value
    texts = []
    if "min_length" in limits:
        texts.append(f"{limits['min_length']} to {limits['max_length']} {unit}")
    elif "max_length" in limits:
        texts.append(f"up to {limits['max_length']} {unit}")
    if "ge" in limits and "le" in limits:
        texts.append(f"{_number(limits['ge'])} to {_number(limits['le'])}")
    else:
        for kind, symbol in (("ge", "≥"), ("gt", ">"), ("le", "≤"), ("lt", "<")):
            if kind in limits:
                texts.append(f"{symbol} {_number(limits[kind])}")
    return texts


def test_every_yaml_example_is_a_valid_study() -> None:
    blocks = _blocks("yaml")
    assert len(blocks) >= 3
    kinds = set()
    for block in blocks:
        study = StudyCreate.model_validate(yaml.safe_load(block))
        kinds.add(study.space.type)
        if isinstance(study.space, TemplateSpace):  # and it expands to a robot
            check_template(study.space.template, study.space.params)
    assert kinds == {"box", "design", "template"}


@pytest.mark.parametrize("model_name", sorted(TABLES))
def test_field_table_lists_every_field_with_its_default_and_range(model_name: str) -> None:
    model = TABLES[model_name]
    rows = _table(model_name)
    assert set(rows) == set(model.model_fields), f"{model_name}: table and model differ"
    for name, field in model.model_fields.items():
        type_cell, default_cell, _meaning = rows[name]
        where = f"{model_name}.{name}"
        if field.is_required():
            assert default_cell == "required", where
        else:
            literal = re.match(r"`([^`]*)`", default_cell)
            assert literal, f"{where}: default {default_cell!r} is not a `literal`"
            annotation: Any = field.annotation
            if field.metadata:
                annotation = Annotated[(annotation, *field.metadata)]
            adapter = TypeAdapter(annotation)
            documented = adapter.validate_python(yaml.safe_load(literal.group(1)))
            assert documented == field.get_default(call_default_factory=True), where
        unit = "characters" if field.annotation is str else "items"
        for text in _range_texts(field.metadata, unit):
            assert text in type_cell.replace(",", ""), f"{where}: {text!r} not in {type_cell!r}"


def test_bound_fields_are_named() -> None:
    for name in Bound.model_fields:
        assert f"{name}:" in DOC


def test_error_example_is_what_validation_answers() -> None:
    body = yaml.safe_load((ROOT / "examples" / "stand-up.yaml").read_text(encoding="utf-8"))
    body["space"]["parts"]["link"]["length"] = {"low": 0.6, "high": 0.25}
    with pytest.raises(ValidationError) as caught:
        StudyCreate.model_validate(body)
    problems = [
        ".".join(str(part) for part in error["loc"])
        + ": "
        + str(error["msg"]).removeprefix("Value error, ")
        for error in caught.value.errors()
    ]
    (answer,) = [json.loads(block) for block in _blocks("json")]
    assert answer == {"error": "invalid", "detail": "; ".join(problems), "problems": problems}


def _names(cell: str) -> set[str]:
    return set(re.findall(r"`([^`]+)`", cell))


def test_proposer_names_and_options_match_the_registry() -> None:
    proposers = pytest.importorskip("adservice.proposers")
    assert _names(_table("ProposerConfig")["name"][0]) == set(proposers.available())
    section = DOC.split("## Proposer", 1)[1].split("\n## ", 1)[0]
    rows = dict(re.findall(r"^\| `([a-z-]+)` \| (.*)$", section, re.M))
    assert set(proposers.available()) <= set(rows)
    for name in proposers.available():
        documented = _names(rows[name].rsplit(" | ", 1)[1])
        assert set(proposers.options_model(name).model_fields) <= documented, name


def test_task_and_learner_names_and_budgets_match_the_catalogue() -> None:
    pytest.importorskip("pybullet")
    installed = catalogue()
    rows = _table("NewTaskConfig")
    assert _names(rows["name"][0]) == set(installed.tasks)
    assert _names(rows["learner"][0]) == set(installed.learners)
    budgets = rows["train_steps"][2]
    for name, spec in installed.learners.items():
        learner = spec.load_factory()
        assert name in budgets and f"{learner.default_steps:,}" in budgets, name
