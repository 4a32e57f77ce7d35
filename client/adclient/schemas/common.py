"""What every body of the API shares: the limits of names and free text, the states
of studies and trials, the strict base model, and the checks of free JSON fields and
user attributes."""

from __future__ import annotations

import json
import math
import unicodedata
from enum import StrEnum
from typing import Annotated, Any

from pydantic import (
    AfterValidator,
    Field,
)

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
MAX_WORKER_PAGE = 1000
"""The most workers one ``GET /workers`` (or ``/studies/{id}/workers``) answers, newest
first: a fleet whose pods take new ids on each restart makes more over time."""
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


def plain_text(value: Any, where: str, *, finite: bool = False) -> Any:
    """Refuse strings that cannot be stored and sent back: NUL (PostgreSQL cannot store
    it) and lone surrogates (not encodable as UTF-8), anywhere in a JSON value. With
    ``finite``, refuse NaN and infinite numbers too (not JSON: PostgreSQL refuses them,
    answers drop them), and integers past 64 bits (what JSON readers other than
    Python's take; a browser reads one past the float range as Infinity); new studies
    are checked so, while studies already stored keep loading."""
    if finite and isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"{where}: numbers must be finite, got {value!r}")
    if finite and isinstance(value, int) and not -(2**63) <= value < 2**63:
        raise ValueError(
            f"{where}: integers must fit in 64 bits (-2^63 to 2^63 - 1), got one of "
            f"{len(str(abs(value)))} digits"
        )
    if isinstance(value, str):
        if "\x00" in value:
            raise ValueError(f"{where}: text must not contain NUL")
        try:
            value.encode("utf-8")
        except UnicodeEncodeError:
            raise ValueError(f"{where}: text must be valid Unicode (no lone surrogates)") from None
    elif isinstance(value, dict):
        for key, item in value.items():
            plain_text(key, f"{where} key")
            plain_text(item, f"{where}.{key}", finite=finite)
    elif isinstance(value, list):
        for index, item in enumerate(value):
            plain_text(item, f"{where}[{index}]", finite=finite)
    return value


def finite(value: float, what: str) -> float:
    if not math.isfinite(value):
        raise ValueError(f"{what} must be a finite number, got {value!r}")
    return value


def json_depth(value: Any, limit: int) -> int:
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
    if json_depth(value, MAX_JSON_DEPTH) > MAX_JSON_DEPTH:
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
    if json_depth(value, MAX_JSON_DEPTH) <= MAX_JSON_DEPTH:
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


def bounded_user_attrs(attrs: dict[str, Any], *, values: bool = True) -> dict[str, Any]:
    """User attributes within the limits of every free JSON field (depth, plain text,
    finite numbers within 64 bits), keys of 1 to ``MAX_USER_ATTR_KEY`` characters, and at
    most ``MAX_USER_ATTRS_BYTES`` encoded: checked on a request and again once merged,
    then without ``values`` (the changes' were checked, and the stored ones stay as an
    older server let them in: an integer past 64 bits must not block other keys)."""
    if values:
        plain_text(attrs, "user_attrs", finite=True)
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
