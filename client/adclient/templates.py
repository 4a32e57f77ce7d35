"""Your own robot as a template: a URDF or xacro text whose numbers are searched.

A template space's params are the template's xacro arguments (``$(arg name)``, with or
without a ``<xacro:arg>`` declaring them) or properties (``${name}`` in any attribute,
whether or not the file declares ``<xacro:property name="name">``): :func:`expand`
hands each param's value to all three, so a declared property's value is replaced and
an undeclared one is defined before the first element. The result is a plain URDF.

A template's ``${...}`` is in the template language of :mod:`adclient.template_expr`
(numbers, texts, arithmetic, comparisons, named math functions), never Python: its
xacro is hardened (:func:`_harden_xacro`) so that this is xacro's only evaluator,
``$(arg name)`` its only substitution, and ``xacro:include`` does not exist, however the
text spells them; :func:`template_problems` names the plain spellings before anything
runs. A template and its output are XML as data: no DTD, entity or processing
instruction, and every name xacro writes an XML name (:func:`expand`). Still a template
is expanded in a child process of its own (:func:`expand_checked`), limited in memory
and time and without the parent's environment, which checks each URDF there (its
bytes, and the robot it builds): a server checking a stranger's template, or a worker
building it, cannot be made to hang, exhaust memory or read a setting, and never
parses a URDF that has not passed those checks.
"""

from __future__ import annotations

import json
import math
import os
import re
import signal
import sys
import threading
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from adclient.xml_data import plain_data_problem, xml_name_problem

XACRO_NS = "http://www.ros.org/wiki/xacro"

EXPAND_SECONDS = 20
"""CPU limit of one isolated expansion (a batch of points). Its wall-clock limit is a
second more: a child with a core to itself meets the CPU limit first, a stalled or
starved one the clock."""
EXPAND_MEMORY = 1 << 30
"""Address-space limit of the expanding process (bytes)."""
MAX_URDF_BYTES = 2_000_000
"""The largest expanded URDF accepted (bytes; a server may set less:
``AD_MAX_URDF_BYTES``). A robot of a hundred links of primitives takes about 50 kB."""

_FORBIDDEN = (
    (
        re.compile(r"<\s*[\w.-]+:include\b"),
        "xacro:include (a template stands alone: inline the file)",
    ),
    (re.compile(r"\$\(\s*find\b"), "$(find ...) (a template stands alone: no packages)"),
    (re.compile(r"\$\(\s*(?:env|optenv)\b"), "$(env ...) and $(optenv ...) (no environment)"),
    (re.compile(r"\$\(\s*dirname\b"), "$(dirname) (a template has no file)"),
    (re.compile(r"\b(?:load_yaml|abs_filename)\b"), "xacro.load_yaml and abs_filename (no files)"),
    (re.compile(r"\$\(\s*(?:eval|cwd)\b"), "$(eval ...) and $(cwd) (use ${...})"),
)
_IDENTIFIER = re.compile(r"[A-Za-z_]\w*")
_DECLARATION = re.compile(
    r"^<\s*[\w.-]+:(?:arg|property)\s.*?\bname\s*=\s*[\"']([^\"']*)[\"']", re.S
)

_XACRO_LOCK = threading.Lock()
"""xacro keeps its arguments and file stack in module globals: one expansion at a time."""


class TemplateError(ValueError):
    """A template that does not expand, or expands to no robot the worker can build."""


def template_problems(template: str, names: Iterable[str]) -> list[str]:
    """What can be told of a template from its text alone: a DTD, entity or processing
    instruction (:func:`adclient.xml_data.plain_data_problem`, with its line),
    constructs that would read files or the environment, and params it never uses. Each
    in one pass over the text (no pattern that rescans it), so a megabyte of unclosed
    ``<!--`` or ``${`` costs no more than a megabyte of anything else. The child that
    expands the template refuses the same constructs however they are spelt
    (:func:`_harden_xacro`, :func:`expand`)."""
    text = "".join(_pieces(template, "<!--", "-->", keep_outside=True))
    problems = [
        f"template: {what} is not allowed" for pattern, what in _FORBIDDEN if pattern.search(text)
    ]
    not_data = plain_data_problem(template)
    if not_data is not None:
        problems.insert(0, f"template: {not_data}")
    used: set[str] = set()
    for expression in _pieces(text, "${", "}", keep_outside=False):
        used.update(_IDENTIFIER.findall(expression))
    for call in _pieces(text, "$(", ")", keep_outside=False):
        words = call.split()
        if len(words) == 2 and words[0] == "arg":
            used.add(words[1])
    for tag in _pieces(text, "<", ">", keep_outside=False):
        declared = _DECLARATION.match("<" + tag)
        if declared:
            used.add(declared.group(1))
    for name in names:
        if name not in used:
            problems.append(
                f"params: {name!r} is not used by the template (give it as $(arg {name}) or "
                f'${{{name}}}, or declare <xacro:arg name="{name}"> or '
                f'<xacro:property name="{name}">)'
            )
    return problems


def _pieces(text: str, opening: str, closing: str, *, keep_outside: bool) -> Iterator[str]:
    """The text between each ``opening`` and the next ``closing`` (or, with
    ``keep_outside``, the text outside them), in one pass; an unclosed opening ends it."""
    at = 0
    while True:
        start = text.find(opening, at)
        if start < 0:
            if keep_outside:
                yield text[at:]
            return
        end = text.find(closing, start + len(opening))
        if keep_outside:
            yield text[at:start]
        if end < 0:
            return
        if not keep_outside:
            yield text[start + len(opening) : end]
        at = end + len(closing)


def _text(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    return str(value)


def expand(template: str, values: Mapping[str, Any]) -> str:
    """The URDF of the template at these param values (in this process: see
    :func:`expand_checked` for a template you did not write); TemplateError naming
    the line where one can be told. The template is read as data (no DTD, entity or
    processing instruction: :mod:`adclient.xml_data`), every element and attribute name
    in the result is an XML name (``xacro:element`` and ``xacro:attribute`` write names
    from values), and the result is its root element alone: nothing before it."""
    import xml.parsers.expat

    import xacro
    from defusedxml import DefusedXmlException
    from defusedxml.minidom import parseString

    not_data = plain_data_problem(template)
    if not_data is not None:
        raise TemplateError(f"template: {not_data}")
    with _XACRO_LOCK:
        _harden_xacro()
        try:
            doc = xacro.parse(parseString(template, forbid_dtd=True))
        except xml.parsers.expat.ExpatError as error:
            raise TemplateError(
                f"template: line {error.lineno}, column {error.offset}: "
                f"{xml.parsers.expat.ErrorString(error.code)}"
            ) from None
        except DefusedXmlException as error:  # refused above already: never reached
            raise TemplateError(f"template: {type(error).__name__}") from None
        root = doc.documentElement
        if root.getAttribute("xmlns:xacro") != XACRO_NS:  # xacro reads only this prefix
            root.setAttribute("xmlns:xacro", XACRO_NS)
        declared_properties = {
            element.getAttribute("name"): element
            for element in root.childNodes
            if element.nodeType == element.ELEMENT_NODE and element.tagName == "xacro:property"
        }
        mappings = {name: _text(value) for name, value in values.items()}
        for name, text in mappings.items():
            element = declared_properties.get(name)
            if element is None:
                element = doc.createElement("xacro:property")
                element.setAttribute("name", name)
                root.insertBefore(element, root.firstChild)
            for attribute in ("default", "value"):
                if element.hasAttribute(attribute):
                    element.removeAttribute(attribute)
            element.setAttribute("value", text)
        try:
            xacro.process_doc(doc, mappings=mappings, verbosity=0)
        except Exception as error:  # xacro raises its own and Python's (NameError...)
            raise TemplateError(_located(template, error)) from None
        finally:
            xacro.init_stacks(None)
        root = doc.documentElement
        _check_names(root)
        try:
            return '<?xml version="1.0" ?>\n' + str(root.toprettyxml(indent="  "))
        except ValueError as error:  # minidom's: a comment or CDATA it cannot write
            raise TemplateError(f"template: its expansion cannot be written: {error}") from None


def _check_names(root: Any) -> None:
    """Every element's and attribute's name an XML name, or TemplateError naming it."""
    stack = [root]
    while stack:
        node = stack.pop()
        if node.nodeType != node.ELEMENT_NODE:
            continue
        problem = xml_name_problem(node.tagName)
        if problem is not None:
            raise TemplateError(
                f"template: an element's name {problem} (as is the xacro:name of an xacro:element)"
            )
        for name, _ in node.attributes.items():
            problem = xml_name_problem(name)
            if problem is not None:
                raise TemplateError(
                    f"template: <{node.tagName}>: an attribute's name {problem} (as is the "
                    "name of an xacro:attribute)"
                )
        stack.extend(node.childNodes)


def _harden_xacro() -> None:
    """xacro, as a template may use it: ``$(arg name)`` its only substitution (no
    ``eval``, ``env``, ``optenv``, ``find``, ``dirname``, ``cwd``, however the text spells
    them: a ``${...}`` inside ``$(...)`` is evaluated first), no ``xacro:include`` (also
    one made by ``xacro:element``), and ``${...}`` (also ``xacro:if``, property values,
    macro arguments) in the template language of :mod:`adclient.template_expr` instead of
    Python's ``eval``: xacro's every evaluation goes through ``safe_eval``. Idempotent."""
    import xacro
    from xacro import substitution_args

    from adclient.template_expr import evaluate

    def template_eval(expression: str, symbols: Any, _: Any = None) -> Any:
        """xacro's ``safe_eval``: its names the template's properties and macro
        arguments, found in the tables up to (never in) xacro's Python symbols."""

        def lookup(name: str) -> Any:
            table = symbols
            while isinstance(table, xacro.Table):
                if dict.__contains__(table, name):
                    return table[name]  # a lazy property is evaluated here
                table = table.parent
            raise KeyError(name)

        return evaluate(str(expression), lookup)

    def only_args(text: str) -> str:
        for call in substitution_args._collect_args(text):
            word = call.split()[0] if call.split() else ""
            if word != "arg":
                raise xacro.XacroException(f"$({word} ...) is not allowed in a template")
        resolved: str = substitution_args._resolve_args(
            text, xacro.substitution_args_context, {"arg": substitution_args._arg}
        )
        return resolved

    def no_include(*_: Any) -> None:
        raise xacro.XacroException("xacro:include is not allowed: a template stands alone")

    xacro.eval_extension = only_args
    xacro.process_include = no_include
    xacro.safe_eval = template_eval


def _located(template: str, error: Exception) -> str:
    """xacro's message, with the template line of the expression it names."""
    cause = getattr(error, "exc", None) or error  # xacro wraps Python's errors
    message = " ".join(str(error).split())
    import xacro

    from adclient.template_expr import ExpressionError

    if not isinstance(cause, xacro.XacroException | ExpressionError):
        message = f"{type(cause).__name__}: {message}" if message else type(cause).__name__
    quoted = re.search(r"when evaluating expression '(.*?)'", message)
    if quoted:
        for number, line in enumerate(template.splitlines(), start=1):
            if quoted.group(1) in line:
                return f"template: line {number}: {message}"
    return f"template: {message}"


@dataclass(frozen=True)
class ByteLimit:
    """A limit on the bytes of expanded URDFs, and how a refusal names it."""

    bytes: int
    named: str = ""
    """E.g. "the limit of 2,000,000 bytes (AD_MAX_URDF_BYTES)"; default: the bytes."""

    def text(self) -> str:
        return self.named or f"the limit of {self.bytes:,} bytes"


@dataclass(frozen=True)
class Expanded:
    """A template at one point, checked: its URDF, or why there is none (``stage``:
    ``expand`` the template did not expand; ``robot`` its URDF is too large or builds
    no robot; ``links`` it lacks a link the task looks up)."""

    urdf: str | None = None
    error: str | None = None
    stage: str = "expand"

    def message(self, where: str = "") -> str:
        """Why it is refused, ``where`` (e.g. "at the params' lows") said for a URDF."""
        if self.stage == "robot":
            return f"template, expanded{' ' + where if where else ''}: {self.error}"
        return str(self.error)


def expand_checked(
    template: str,
    points: Sequence[Mapping[str, Any]],
    *,
    links: Iterable[tuple[str, str]] = (),
    max_bytes: ByteLimit | None = None,
    max_total_bytes: ByteLimit | None = None,
    robots: bool = True,
) -> list[Expanded]:
    """:func:`expand` at each point, in one child process limited to ``EXPAND_MEMORY``
    and ``EXPAND_SECONDS`` of CPU for all of them, that inherits no environment but the
    import path and is confined further where this machine allows
    (:mod:`adclient.template_child`). Each URDF is checked there: at most ``max_bytes``
    (default ``MAX_URDF_BYTES``), all of them together at most ``max_total_bytes`` (a
    point past it is refused), and with ``robots`` a robot the worker can build
    (:func:`adclient.urdf_model.read_urdf`) having the links a task looks up
    (``(option, link)`` pairs). Points the child did not reach in its time are refused
    with the limit it ran out of."""
    import subprocess  # here: the child, which imports this module, needs none of it

    limit = max_bytes or ByteLimit(MAX_URDF_BYTES)
    request = {
        "template": template,
        "points": [dict(point) for point in points],
        "robots": robots,
        "links": [list(pair) for pair in links],
        "max_bytes": [limit.bytes, limit.text()],
        "max_total_bytes": None
        if max_total_bytes is None
        else [max_total_bytes.bytes, max_total_bytes.text()],
    }
    command, env = child_command()
    seconds = EXPAND_SECONDS
    try:
        done = subprocess.run(
            command,
            input=json.dumps(request).encode(),
            capture_output=True,
            timeout=seconds + 1,
            env=env,
            check=False,
        )
        output, returncode = done.stdout, done.returncode
        stopped = f"template: expanding it failed (exit {returncode})"
        if returncode == -signal.SIGXCPU:
            stopped = f"template: expanding it took over {seconds} s of CPU"
        elif returncode != 0:
            last = (done.stderr.decode(errors="replace").strip().splitlines() or [""])[-1]
            stopped = f"{stopped} {last[:200]}".strip()
    except subprocess.TimeoutExpired as timeout:
        output = timeout.stdout or b""
        stopped = f"template: expanding it took over {seconds + 1} s"
    answers: dict[int, Expanded] = {}
    for line in output.splitlines():
        try:
            answer = json.loads(line)
        except ValueError:  # the line the child was writing when it was stopped
            continue
        if "isolation" in answer:
            _warn_missing_isolation(answer["isolation"].get("missing", {}))
        elif "point" in answer:
            answers[answer["point"]] = Expanded(
                answer.get("urdf"), answer.get("error"), answer.get("stage", "expand")
            )
    results = []
    for index in range(len(points)):
        if index in answers:
            results.append(answers[index])
            continue
        before = f" (with the {index} points before it in its batch)" if index else ""
        results.append(Expanded(error=stopped + before))
    return results


def expand_isolated(template: str, points: Sequence[Mapping[str, Any]]) -> list[str]:
    """The URDF of each point (:func:`expand_checked`, without the robot checks);
    TemplateError naming the first point that does not expand."""
    expanded = expand_checked(template, points, robots=False)
    for result in expanded:
        if result.urdf is None:
            raise TemplateError(result.message())
    return [str(result.urdf) for result in expanded]


_WARNED_MISSING: set[str] = set()


def _warn_missing_isolation(missing: Mapping[str, str]) -> None:
    """Logs, once a process, each layer of the child's confinement this machine lacks
    (a template still expands without it: the layers are defence in depth)."""
    new = {layer: why for layer, why in missing.items() if layer not in _WARNED_MISSING}
    if new:
        import logging

        _WARNED_MISSING.update(new)
        logging.getLogger(__name__).warning(
            "the template-expanding child runs without %s (see docs/security.md)",
            "; ".join(f"{layer}: {why}" for layer, why in sorted(new.items())),
        )


def child_command() -> tuple[list[str], dict[str, str]]:
    """The expanding child's command line and its whole environment: template_child.py
    as a script, without site (-S) or its own folder (-P) on the path (the child imports
    xacro, PyYAML, defusedxml, the standard library, this module and the URDF reader,
    not the rest of the SDK: it
    starts in half the time); argv: its memory (bytes), its CPU seconds, and where it
    makes (and at once removes) the empty folder it takes for its root."""
    import tempfile

    child = os.path.join(os.path.dirname(os.path.abspath(__file__)), "template_child.py")
    limits = [str(EXPAND_MEMORY), str(EXPAND_SECONDS), tempfile.gettempdir()]
    return [sys.executable, "-S", "-P", child, *limits], {
        "PATH": os.defpath,
        "PYTHONPATH": _child_path(),
    }


def _child_path() -> str:
    """Where the child finds xacro, PyYAML, defusedxml and adclient (without ``site``,
    nothing else is on its path): their folders, then this process's PYTHONPATH."""
    import importlib.util

    folders = [os.path.dirname(os.path.dirname(os.path.abspath(__file__)))]
    for name in ("xacro", "yaml", "defusedxml"):
        spec = importlib.util.find_spec(name)
        if spec is None or spec.origin is None:
            raise TemplateError(f"template: {name} is not installed here")
        folders.append(os.path.dirname(os.path.dirname(spec.origin)))
    folders += [folder for folder in os.environ.get("PYTHONPATH", "").split(os.pathsep) if folder]
    return os.pathsep.join(dict.fromkeys(folders))


def check_points(params: Sequence[Any]) -> list[tuple[str, dict[str, Any]]]:
    """Where a template space is checked: every param at its low, at its middle and at
    its high end (a categorical's first, middle and last choice); a template without
    params at its one design."""
    if not params:
        return [("its one design (no params)", {})]
    points: list[tuple[str, dict[str, Any]]] = []
    for where in ("low", "middle", "high"):
        point: dict[str, Any] = {}
        for param in params:
            if param.type == "categorical":
                choices = list(param.choices)
                point[param.name] = choices[
                    {"low": 0, "middle": len(choices) // 2, "high": -1}[where]
                ]
                continue
            low, high = float(param.low), float(param.high)
            if where == "middle":
                value = math.sqrt(low * high) if param.log else (low + high) / 2
                if param.type == "int" or param.step is not None:
                    step = param.step or 1
                    value = low + round((value - low) / step) * step
            else:
                value = low if where == "low" else high
            point[param.name] = int(value) if param.type == "int" else float(value)
        points.append((f"the params' {where}" + (" values" if where == "middle" else "s"), point))
    return points


def check_template(
    template: str,
    params: Sequence[Any],
    links: Iterable[tuple[str, str]] = (),
    *,
    max_bytes: ByteLimit | None = None,
) -> None:
    """The template expands, at each of :func:`check_points`, to a robot the worker
    can build (:func:`adclient.urdf_model.read_urdf`) having the links a task looks up
    (``(option, link)`` pairs), within ``max_bytes``; TemplateError naming the point
    and the problem."""
    problems = template_problems(template, [param.name for param in params])
    if problems:
        raise TemplateError("; ".join(problems))
    points = check_points(params)
    expanded = expand_checked(
        template, [point for _, point in points], links=links, max_bytes=max_bytes
    )
    for (where, _), result in zip(points, expanded, strict=True):
        if result.urdf is None:
            raise TemplateError(result.message(f"at {where}"))
