"""Reading trials back in: the JSON that ``adclient export`` writes, or a CSV with one
column per param (``x`` or ``params_x``, as the CSV export names them) and a ``value``
column (``state``, ``message`` and ``metrics_<name>`` columns are read when present).
A file may start with a byte-order mark, as Excel saves one; a CSV's text cells come back
as they were before the export made them formula-safe (:func:`adclient.export.unescaped`).

Pure functions: :func:`read_import` turns a file's text into what to create and add;
the CLI sends it. Finished trials (complete, failed, pruned) come in as evaluations the
proposer learns from; unfinished ones (queued, running, paused) are enqueued to be
evaluated again, unless left out.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from pydantic import ValidationError

from adclient.errors import quoted
from adclient.export import CSV_FIELDS, unescaped
from adclient.schemas import MAX_JSON_DEPTH, BoxSpace, StudyCreate, TrialAdd
from adclient.schemas.common import json_depth

FINISHED = ("complete", "failed", "pruned")
EXPORT_DEPTH = MAX_JSON_DEPTH + 3
"""How deep an export nests at most: a free JSON field (a trial's user attributes, a
proposer's options) three levels in (the file's object, the list of trials, a trial)."""


class ImportFileError(ValueError):
    """A file that cannot be imported; the message names the row or field."""


@dataclass(frozen=True)
class ImportPlan:
    study: dict[str, Any] | None
    """A new study's body (from an export's study), or None (a CSV: no space in it)."""
    trials: list[TrialAdd]
    left_out: int
    """Unfinished trials not imported (``queue_unfinished=False``)."""


def read_import(
    text: str,
    *,
    format: str,
    space: dict[str, Any] | None = None,
    queue_unfinished: bool = True,
) -> ImportPlan:
    """``format``: ``json`` (an export) or ``csv``; ``space``: the space of the study the
    trials go to (a CSV's cells are read in its params' types)."""
    text = text.removeprefix("\ufeff")
    if format == "json":
        return _from_export(text, queue_unfinished=queue_unfinished)
    if format == "csv":
        return _from_csv(text, space=space, queue_unfinished=queue_unfinished)
    raise ImportFileError(f"unknown format {format!r}: json or csv")


def _trial(row: dict[str, Any], where: str, queue_unfinished: bool) -> TrialAdd | None:
    told = row.get("value") is not None or row.get("values") is not None
    state = row.get("state") or ("complete" if told else "queued")
    if state not in FINISHED:
        if not queue_unfinished:
            return None
        row = {"params": row["params"]}  # evaluated again: its partial outcome is not one
    else:
        row = {**row, "state": state}
    try:
        return TrialAdd.model_validate(row)
    except ValidationError as exc:
        problems = "; ".join(
            f"{'.'.join(str(part) for part in error['loc']) or 'trial'}: {error['msg']}"
            for error in exc.errors()
        )
        raise ImportFileError(f"{where}: {problems}") from None


def load_json(text: str, *, deepest: int) -> Any:
    """JSON text whose objects and arrays nest at most ``deepest`` levels; deeper is an
    :class:`ImportFileError`, since it exhausts Python's stack, in the parser or when the
    value is sent on (text that is not JSON: ``json.JSONDecodeError``)."""
    try:
        value = json.loads(text)
    except RecursionError:
        value = None  # the parser gave up: deeper than any limit
    else:
        if json_depth(value, deepest) <= deepest:
            return value
    raise ImportFileError(f"objects and arrays nest deeper than {deepest} levels")


def _from_export(text: str, *, queue_unfinished: bool) -> ImportPlan:
    try:
        payload = load_json(text, deepest=EXPORT_DEPTH)
    except json.JSONDecodeError as exc:
        raise ImportFileError(f"not JSON: {exc}") from None
    if not isinstance(payload, dict) or not isinstance(payload.get("trials"), list):
        raise ImportFileError("not an export: a JSON object with 'study' and 'trials' expected")
    study = payload.get("study")
    body = None
    if isinstance(study, dict):
        body = {key: study[key] for key in StudyCreate.model_fields if key in study}
        _one_way_of_objectives(body)
    rows: list[tuple[str, dict[str, Any]]] = []
    numbered = sorted(
        payload["trials"], key=lambda t: t.get("number", 0) if isinstance(t, dict) else 0
    )
    for index, item in enumerate(numbered):
        if not isinstance(item, dict) or not isinstance(item.get("params"), dict):
            raise ImportFileError(f"trials[{index}]: an object with 'params' expected")
        row = {
            key: item[key]
            for key in ("params", "state", "value", "values", "message", "metrics")
            if item.get(key) is not None
        }
        rows.append((f"trial number {item.get('number', index)}", row))
    return _plan(body, rows, queue_unfinished)


def _one_way_of_objectives(body: dict[str, Any]) -> None:
    """An exported study names its objectives three ways (``direction``, ``directions``
    with ``objective_names``, and ``objectives`` where read from metrics); a new study
    takes one."""
    directions = body.get("directions") or []
    if body.get("objectives"):
        keep = "objectives"
    elif len(directions) > 1:
        keep = "directions"
    else:
        keep = "direction"
    for key in ("direction", "directions", "objective_names", "objectives"):
        if key != keep and not (keep == "directions" and key == "objective_names"):
            body.pop(key, None)
    if not body.get("reference_point"):
        body.pop("reference_point", None)


def _from_csv(text: str, *, space: dict[str, Any] | None, queue_unfinished: bool) -> ImportPlan:
    try:
        return _read_csv(text, space=space, queue_unfinished=queue_unfinished)
    except csv.Error as exc:  # a NUL byte, a cell past the csv module's size limit
        raise ImportFileError(f"not a CSV: {exc}") from None


def _read_csv(text: str, *, space: dict[str, Any] | None, queue_unfinished: bool) -> ImportPlan:
    reader = csv.DictReader(io.StringIO(text))
    columns = reader.fieldnames or []
    _one_column_each(columns)
    several = sorted(
        (c for c in columns if c.startswith("values_") and c[7:].isdigit()),
        key=lambda c: int(c[7:]),
    )
    if "value" not in columns and "state" not in columns and not several:
        raise ImportFileError(
            "a CSV needs a 'value' column, or 'values_<objective>' columns (and optionally 'state')"
        )
    typed = _box_types(space)
    rows: list[tuple[str, dict[str, Any]]] = []
    for line, cells in enumerate(reader, start=2):
        params: dict[str, Any] = {}
        metrics: dict[str, Any] = {}
        values: dict[str, float] = {}
        row: dict[str, Any] = {}
        for column, cell in cells.items():
            if column is None or cell is None or cell == "":
                continue
            cell = unescaped(cell)
            if column.startswith("metrics_"):
                metrics[column.removeprefix("metrics_")] = _number(cell, f"line {line}, {column}")
            elif column == "value":
                row["value"] = _number(cell, f"line {line}, value")
            elif column in several:
                values[column] = _number(cell, f"line {line}, {column}")
            elif column in ("state", "message"):
                row[column] = cell
            elif column.startswith("params_") or not _about_the_run(column):
                name = column.removeprefix("params_")
                params[name] = _param(cell, typed.get(name), f"line {line}, {column}")
        row["params"] = params
        if values:
            row["values"] = [values[column] for column in several if column in values]
        if metrics:
            row["metrics"] = metrics
        rows.append((f"line {line}", row))
    return _plan(None, rows, queue_unfinished)


def _plan(
    study: dict[str, Any] | None, rows: list[tuple[str, dict[str, Any]]], queue_unfinished: bool
) -> ImportPlan:
    trials: list[TrialAdd] = []
    left_out = 0
    for where, row in rows:
        trial = _trial(row, where, queue_unfinished)
        if trial is None:
            left_out += 1
        else:
            trials.append(trial)
    return ImportPlan(study=study, trials=trials, left_out=left_out)


def _one_column_each(columns: Sequence[str]) -> None:
    """Refuse a header that names a column twice (``x,x``, or ``x,params_x``: one param):
    the csv module would keep a row's last cell of the name and drop the others."""
    seen: dict[tuple[bool, str], str] = {}
    for column in columns:
        param = column.startswith("params_") or not _about_the_run(column)
        key = (param, column.removeprefix("params_") if param else column)
        if key in seen and seen[key] == column:
            raise ImportFileError(f"the header names column {column!r} twice")
        if key in seen:
            raise ImportFileError(f"columns {seen[key]!r} and {column!r} name one param")
        seen[key] = column


def _about_the_run(column: str) -> bool:
    """A column of the CSV export that is not a param (the run's own, feasibility, the
    trial a controller started from, user attributes: they do not come back in)."""
    return (
        column in CSV_FIELDS
        or column in ("feasible", "transfer_from")
        or column.startswith("user_attrs_")
    )


def _box_types(space: dict[str, Any] | None) -> dict[str, Any]:
    """A box's or a template's params by name (a CSV's cells are read in their types)."""
    if space is None or space.get("type") not in ("box", "template"):
        return {}
    box = BoxSpace.model_validate({"type": "box", "params": space["params"]})
    return {param.name: param for param in box.params}


def _number(cell: str, where: str) -> float:
    try:
        return float(cell)
    except ValueError:
        raise ImportFileError(f"{where}: {quoted(cell)} is not a number") from None


def _param(cell: str, param: Any, where: str) -> Any:
    """A cell in its param's type: an int, a float, one of the choices (matched as the
    export writes them), else JSON (a design's lists) or a number or the text itself."""
    if param is not None and param.type == "categorical":
        for choice in param.choices or []:
            if cell == (choice if isinstance(choice, str) else json.dumps(choice)) or cell == str(
                choice
            ):
                return choice
        raise ImportFileError(f"{where}: {quoted(cell)} is not one of {param.choices}")
    if param is not None:
        number = _number(cell, where)
        return int(number) if param.type == "int" and number.is_integer() else number
    try:
        return load_json(cell, deepest=MAX_JSON_DEPTH)
    except json.JSONDecodeError:
        return cell
    except ImportFileError as exc:
        raise ImportFileError(f"{where}: {exc}") from None
