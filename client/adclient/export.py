"""A study and its trials as text: JSON, or CSV in the manner of Optuna's
``trials_dataframe``.

The CSV is made to be opened in a spreadsheet, and its text is whatever users and
workers wrote (messages, categorical choices, user attributes), so no text cell may read
as a formula (OWASP's CSV injection rule): a text cell that does not start with a letter,
a digit or inert punctuation gets a leading ``'``, which a spreadsheet reads as "this is
text" (and :func:`unescaped` takes off again on import), and every text cell is quoted,
so a ``;`` in it cannot start a new cell where a spreadsheet splits on ``;``. Numbers are
written bare and stay numbers (``-1.5`` is a number, never escaped).
"""

from __future__ import annotations

import csv
import io
import json
import string
from collections.abc import Mapping
from datetime import datetime
from typing import Any, Literal

from adclient.schemas import Study, Trial

ExportFormat = Literal["json", "csv"]

INERT_FIRST = frozenset(string.punctuation) - frozenset("=+-@'")
"""ASCII characters a text cell may start with unescaped, besides letters and digits of
any script. A whitelist: a space, a tab, a carriage return, a full-width equals sign
(U+FF1D) or any other character a spreadsheet might skip or read as a formula's start
is escaped; so is ``'``, so that :func:`unescaped` undoes exactly what
:func:`formula_safe` did."""


CSV_FIELDS = [
    "number",
    "id",
    "state",
    "value",
    "worker_id",
    "attempts",
    "created_at",
    "started_at",
    "finished_at",
    "duration_s",
    "message",
]


def export_json(study: Study, trials: list[Trial]) -> str:
    payload = {
        "study": study.model_dump(mode="json"),
        "trials": [trial.model_dump(mode="json") for trial in trials],
    }
    return json.dumps(payload, indent=2) + "\n"


def export_csv(trials: list[Trial]) -> str:
    """A study of several objectives has a ``values_<i>`` column per objective (in the
    order of its ``objective_names``), as Optuna's ``trials_dataframe``; a study with
    constraints a ``feasible`` column; a study with ``task.transfer`` a ``transfer_from``
    column (the trial each one's controller started from)."""
    rows: list[dict[str, Any]] = []
    value_columns: dict[str, None] = {}
    param_columns: dict[str, None] = {}
    metric_columns: dict[str, None] = {}
    attr_columns: dict[str, None] = {}
    for trial in sorted(trials, key=lambda t: t.number):
        row: dict[str, Any] = {
            "number": trial.number,
            "id": trial.id,
            "state": trial.state.value,
            "value": _cell(trial.value),
            "worker_id": _cell(trial.worker_id),
            "attempts": trial.attempts,
            "created_at": _cell(trial.created_at),
            "started_at": _cell(trial.started_at),
            "finished_at": _cell(trial.finished_at),
            "duration_s": _duration(trial.started_at, trial.finished_at),
            "message": _cell(trial.message),
        }
        if trial.info.get("transfer_from") is not None:
            value_columns.setdefault("transfer_from")
            row["transfer_from"] = trial.info["transfer_from"]
        for index, objective in enumerate(trial.values or []):
            value_columns.setdefault(f"values_{index}")
            row[f"values_{index}"] = _cell(objective)
        if trial.feasible is not None:
            value_columns.setdefault("feasible")
            row["feasible"] = trial.feasible
        for key, value in _flatten(trial.params):
            column = f"params_{key}"
            param_columns.setdefault(column)
            row[column] = _cell(value)
        for key, metric in trial.metrics.items():
            column = f"metrics_{key}"
            metric_columns.setdefault(column)
            row[column] = _cell(metric)
        for key, value in _flatten(trial.user_attrs):
            column = f"user_attrs_{key}"
            attr_columns.setdefault(column)
            row[column] = _cell(value)
        rows.append(row)
    out = io.StringIO()
    writer = csv.DictWriter(
        out,
        fieldnames=[*CSV_FIELDS, *value_columns, *param_columns, *metric_columns, *attr_columns],
        restval="",
        lineterminator="\n",
        quoting=csv.QUOTE_NONNUMERIC,  # text quoted; numbers bare (floats as repr)
    )
    writer.writeheader()
    writer.writerows(rows)
    return out.getvalue()


def _flatten(value: Mapping[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    items: list[tuple[str, Any]] = []
    for key, item in value.items():
        name = f"{prefix}{key}"
        if isinstance(item, Mapping) and item:
            items.extend(_flatten(item, f"{name}."))
        else:
            items.append((name, item))
    return items


def formula_safe(text: str) -> str:
    """``text`` as a CSV cell no spreadsheet reads as a formula."""
    if text and not (text[0].isalnum() or text[0] in INERT_FIRST):
        return "'" + text
    return text


def unescaped(cell: str) -> str:
    """A cell as it was before :func:`formula_safe` (a cell it left alone is unchanged)."""
    if cell.startswith("'") and formula_safe(cell[1:]) != cell[1:]:
        return cell[1:]
    return cell


def _cell(value: Any) -> Any:
    """A number as itself, text made formula-safe, anything else as text of ours."""
    if value is None:
        return ""
    if isinstance(value, str):
        return formula_safe(value)
    if isinstance(value, datetime):
        return value.isoformat()
    if isinstance(value, list | dict | tuple):
        return json.dumps(value, separators=(",", ":"))
    return value


def _duration(start: datetime | None, end: datetime | None) -> float | str:
    if start is None or end is None:
        return ""
    return round((end - start).total_seconds(), 3)
