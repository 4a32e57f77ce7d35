"""The closest valid name for a study file's unknown field: the server refuses
``max_trial`` with "Extra inputs are not permitted"; ``adclient submit`` adds "did you
mean `max_trials`?".

The server checks a study body against the SDK's own schemas (``StudyCreate``), so the
same check here finds the same unknown fields at the same places (``space.box.params.0.hihg``),
and the JSON schema of ``StudyCreate`` names the fields allowed at each place. Only a
refused body is checked again: the server is the judge of what is valid (it may be newer
than this SDK), this only adds a hint to what it said.
"""

from __future__ import annotations

import difflib
import re
from typing import Any

from pydantic import ValidationError

from adclient.schemas import StudyCreate

EXTRA_FIELD = "Extra inputs are not permitted"
"""Pydantic's message for a field a model does not have, as the server words it too."""


def unknown_field_hints(body: dict[str, Any]) -> dict[str, str]:
    """``"max_trial: Extra inputs are not permitted"`` -> ``"max_trials"`` for each
    unknown field of ``body`` that has a close valid name where it stands."""
    try:
        StudyCreate.model_validate(body)
    except ValidationError as exc:
        errors = exc.errors()
    except Exception:  # a hint is a nicety; the server's message stands
        return {}
    else:
        return {}
    schema = StudyCreate.model_json_schema()
    hints = {}
    for error in errors:
        loc = tuple(error.get("loc", ()))
        if error.get("type") != "extra_forbidden" or not loc or not isinstance(loc[-1], str):
            continue
        names = set()
        for node in _nodes_at(schema, schema, loc[:-1]):
            names.update(node.get("properties", {}))
        closest = difflib.get_close_matches(loc[-1], sorted(names), n=1, cutoff=0.6)
        if closest:
            where = ".".join(str(part) for part in loc)
            hints[f"{where}: {error.get('msg', EXTRA_FIELD)}"] = closest[0]
    return hints


def with_hints(message: str, hints: dict[str, str]) -> str:
    """The server's message (its problems joined by "; ") with "(did you mean `NAME`?)"
    after each whole problem a hint is for."""
    for problem, name in hints.items():
        whole = re.compile(f"(?:^|; ){re.escape(problem)}(?=; |$)")
        found = whole.search(message)
        if found is not None:
            message = f"{message[: found.end()]} (did you mean `{name}`?){message[found.end() :]}"
    return message


def _options(
    schema: dict[str, Any], node: dict[str, Any], *, tagged: bool = True
) -> list[dict[str, Any]]:
    """What ``node`` may be: ``$ref`` followed, unions opened (but a tagged union kept
    whole while ``tagged``, for its tag in a location to pick its member)."""
    if "$ref" in node:
        target = schema.get("$defs", {}).get(node["$ref"].rsplit("/", 1)[-1])
        return _options(schema, target, tagged=tagged) if isinstance(target, dict) else []
    if tagged and "mapping" in node.get("discriminator", {}):
        return [node]
    branches = [branch for key in ("anyOf", "oneOf", "allOf") for branch in node.get(key, ())]
    if branches:
        return [found for branch in branches for found in _options(schema, branch, tagged=tagged)]
    return [node]


def _nodes_at(
    schema: dict[str, Any], node: dict[str, Any], loc: tuple[Any, ...]
) -> list[dict[str, Any]]:
    """The object schemas of what stands at ``loc`` under ``node`` (a pydantic error's
    location: field names, list indices, dict keys and the tags of tagged unions)."""
    if not loc:
        return _options(schema, node, tagged=False)
    part, rest = loc[0], loc[1:]
    found: list[dict[str, Any]] = []
    for option in _options(schema, node):
        mapping = option.get("discriminator", {}).get("mapping", {})
        if mapping:
            if isinstance(part, str) and part in mapping:  # the member its tag names
                found += _nodes_at(schema, {"$ref": mapping[part]}, rest)
        elif isinstance(part, int) and isinstance(option.get("items"), dict):
            found += _nodes_at(schema, option["items"], rest)
        elif isinstance(part, int) and part < len(option.get("prefixItems", ())):
            found += _nodes_at(schema, option["prefixItems"][part], rest)
        elif isinstance(part, str) and part in option.get("properties", {}):
            found += _nodes_at(schema, option["properties"][part], rest)
        elif isinstance(part, str) and isinstance(option.get("additionalProperties"), dict):
            found += _nodes_at(schema, option["additionalProperties"], rest)
    return found
