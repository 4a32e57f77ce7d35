"""Reading trials back in: the JSON that ``adclient export`` writes, or a CSV with one
column per param (``x`` or ``params_x``, as the CSV export names them) and a ``value``
column (``state``, ``message`` and ``metrics_<name>`` columns are read when present).

Pure functions: :func:`read_import` turns a file's text into what to create and add;
the CLI sends it. Finished trials (complete, failed, pruned) come in as evaluations the
proposer learns from; unfinished ones (queued, running, paused) are enqueued to be
evaluated again, unless left out.
"""

from __future__ import annotations

import csv
import io
import json
from dataclasses import dataclass
from typing import Any

from pydantic import ValidationError

from adclient.export import CSV_FIELDS
from adclient.schemas import BoxSpace, StudyCreate, TrialAdd

FINISHED = ("complete", "failed", "pruned")


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


def _from_export(text: str, *, queue_unfinished: bool) -> ImportPlan:
    try:
        payload = json.loads(text)
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
    reader = csv.DictReader(io.StringIO(text))
    columns = reader.fieldnames or []
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
        raise ImportFileError(f"{where}: {cell!r} is not a number") from None


def _param(cell: str, param: Any, where: str) -> Any:
    """A cell in its param's type: an int, a float, one of the choices (matched as the
    export writes them), else JSON (a design's lists) or a number or the text itself."""
    if param is not None and param.type == "categorical":
        for choice in param.choices or []:
            if cell == (choice if isinstance(choice, str) else json.dumps(choice)) or cell == str(
                choice
            ):
                return choice
        raise ImportFileError(f"{where}: {cell!r} is not one of {param.choices}")
    if param is not None:
        number = _number(cell, where)
        return int(number) if param.type == "int" and number.is_integer() else number
    try:
        return json.loads(cell)
    except json.JSONDecodeError:
        return cell
