"""Reading a study file for ``adclient submit``: YAML (numbers as YAML 1.2 reads them)
or JSON, a parse error named by line and column, no infinite or NaN number, and a
template space's ``template`` given as a path read from the file beside it."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

import yaml

from adclient.cli.common import EXIT_USAGE, fail
from adclient.importing import EXPORT_DEPTH, load_json


class StudyFileLoader(yaml.SafeLoader):
    """PyYAML's safe loader, but ``1e-3`` is a number, as YAML 1.2 and JSON read it
    (YAML 1.1 wants a dot in a float, so PyYAML reads ``1e-3`` as text, which the
    API's strict number fields refuse)."""


StudyFileLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9][0-9_]*)[eE][-+]?[0-9]+$"),
    list("-+.0123456789"),
)

TEXT_KEYS = ("name", "metadata")
"""A study file's keys read as YAML 1.1 reads them: free text stays text there (a commit
``7e12345`` in the metadata is not a number)."""


def read_study_file(path: Path) -> dict[str, Any]:
    try:
        text = path.read_text(encoding="utf-8-sig")  # a byte-order mark, as Windows saves one
    except OSError as exc:  # a file named that is not there (or not readable): bad usage
        fail(f"cannot read {path}: {exc.strerror or exc}", EXIT_USAGE)
    try:
        if path.suffix.lower() == ".json":
            data = load_json(text, deepest=EXPORT_DEPTH)
        else:
            data = yaml.load(text, Loader=StudyFileLoader)  # a SafeLoader
            if isinstance(data, dict):
                as_text = yaml.safe_load(text)
                data.update({key: as_text[key] for key in TEXT_KEYS if key in as_text})
    except RecursionError:  # YAML's parser, nested past the stack
        fail(f"cannot parse {path}: objects and arrays nest too deep")
    except json.JSONDecodeError as exc:
        fail(f"cannot parse {path} at line {exc.lineno}, column {exc.colno}: {exc.msg}")
    except yaml.MarkedYAMLError as exc:
        fail(f"cannot parse {path}{_yaml_error_text(exc)}")
    except (ValueError, yaml.YAMLError) as exc:
        first_line = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        fail(f"cannot parse {path}: {first_line}")
    if not isinstance(data, dict):
        fail(f"{path} must hold a mapping with a study body (name, space, ...)")
    where = _non_finite(data, "")
    if where is not None:
        fail(f"{path}: {where} is a number out of range (JSON has no infinity or NaN)")
    _read_template_file(data, path)
    return data


def _yaml_error_text(exc: yaml.MarkedYAMLError) -> str:
    """Where YAML stopped and why, lines and columns counted from 1: `` at line 2,
    column 1: expected ',' or ']', but got '<stream end>' (while parsing a flow sequence
    from line 1, column 7)``."""
    mark = exc.problem_mark or exc.context_mark
    text = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    text += f": {exc.problem or exc.context or type(exc).__name__}"
    if exc.context and exc.problem:
        start, origin = exc.context_mark, ""
        if start is not None and mark is not None and start.index != mark.index:
            origin = f" from line {start.line + 1}, column {start.column + 1}"
        text += f" ({exc.context}{origin})"
    return text


def _non_finite(value: Any, where: str) -> str | None:
    """Where ``value`` holds an infinite or NaN number (``.inf``, ``1e400``), else None."""
    if isinstance(value, float) and not math.isfinite(value):
        return where or "the file"
    items = (
        value.items()
        if isinstance(value, dict)
        else enumerate(value)
        if isinstance(value, list)
        else ()
    )
    for key, item in items:
        found = _non_finite(
            item, f"{where}[{key}]" if isinstance(key, int) else f"{where}.{key}".lstrip(".")
        )
        if found is not None:
            return found
    return None


def _read_template_file(data: dict[str, Any], path: Path) -> None:
    """A template space's ``template`` given as a file path (no markup in it) is that
    file's text, the path relative to the study file."""
    space = data.get("space")
    if not isinstance(space, dict) or space.get("type") != "template":
        return
    template = space.get("template")
    if not isinstance(template, str) or "<" in template:
        return
    file = path.parent / template
    try:
        space["template"] = file.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) else "not UTF-8 text"
        fail(f"space.template: cannot read {file}: {reason or exc}")
