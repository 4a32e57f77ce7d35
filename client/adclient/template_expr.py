"""The language of a template's ``${...}``: arithmetic, comparisons and math functions on
numbers and short texts; never Python.

xacro evaluates ``${...}`` with Python's ``eval``, and no check of the names an
expression uses can see inside a lambda, a comprehension or a default argument: a
template's robot name could run any command. :func:`evaluate` parses the expression
(``ast.parse``, which builds a tree and runs nothing) and interprets that tree itself,
node by node. It is a whitelist: each kind of node it knows has a rule here, and any
other (attribute access, subscripts, lambdas, comprehensions, f-strings, walrus,
containers...) is refused by name, however it is spelt. Values are bounded (numbers to
``MAX_MAGNITUDE``, texts to ``MAX_TEXT_CHARS``, and a power is refused before it is
computed if its result would pass the bound), and so are the expression's length and
nesting: no expression can burn CPU or memory.

Standard library only: the template child imports it on a minimal path.
"""

from __future__ import annotations

import ast
import functools
import math

# Python's parser imports unicodedata to read a name not in ASCII: imported here, before
# the confined template child could no longer open it
import unicodedata  # noqa: F401
from collections.abc import Callable
from typing import Any

MAX_EXPRESSION_CHARS = 1000
"""The longest expression (the text between ``${`` and ``}``)."""
MAX_DEPTH = 50
"""The deepest nesting of an expression's tree (``1+1+...`` nests once per term)."""
MAX_MAGNITUDE = 1e300
"""The largest number, int or float, an expression may use or make."""
MAX_TEXT_CHARS = 4096
"""The longest text an expression may use or make."""
PARSED_AS = "<template expression>"
"""The file name ``ast.parse`` is given (its audit event names it)."""

CONSTANTS = {"pi": math.pi, "e": math.e, "tau": math.tau}
MATH_FUNCTIONS = frozenset(
    {
        "acos",
        "acosh",
        "asin",
        "asinh",
        "atan",
        "atan2",
        "atanh",
        "ceil",
        "copysign",
        "cos",
        "cosh",
        "degrees",
        "exp",
        "fabs",
        "floor",
        "fmod",
        "hypot",
        "log",
        "log10",
        "log2",
        "pow",
        "radians",
        "sin",
        "sinh",
        "sqrt",
        "tan",
        "tanh",
        "trunc",
    }
)
"""The functions of Python's math module a template may call, as ``sin(x)`` or
``math.sin(x)``: each takes and returns floats (ceil, floor, trunc return ints)."""

Lookup = Callable[[str], Any]
"""A template's property (or macro argument) by name; KeyError for none."""


class ExpressionError(ValueError):
    """An expression the template language refuses, or one whose operation fails."""


def evaluate(expression: str, lookup: Lookup) -> bool | int | float | str:
    """The value of a ``${...}`` expression, its names the template's properties (looked
    up with ``lookup``) and ``CONSTANTS``; ExpressionError naming what is refused or what
    failed, NameError for a name that is neither."""
    text = expression.strip()
    return _Interpreter(text, lookup).value(_parse(text).body, 1)


@functools.lru_cache(maxsize=4096)
def _parse(text: str) -> ast.Expression:
    if len(text) > MAX_EXPRESSION_CHARS:
        raise ExpressionError(
            f"the expression is {len(text)} characters long, over {MAX_EXPRESSION_CHARS}"
        )
    try:
        return ast.parse(text, PARSED_AS, mode="eval")
    except (SyntaxError, ValueError) as error:  # ValueError: a NUL in the text
        reason = error.msg if isinstance(error, SyntaxError) else str(error)
        raise ExpressionError(f"`{_short(text)}` is not an expression: {reason}") from None


def _short(text: str) -> str:
    return text if len(text) <= 80 else text[:77] + "..."


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float)  # bool is an int


def _round(number: float, digits: int | None = None) -> float:
    """Python's round, with at most 400 digits either side of the point (rounding an
    int to ``-digits`` computes ``10**digits``)."""
    if digits is None:
        return round(number)
    if not isinstance(digits, int) or abs(digits) > 400:
        raise ValueError(f"round's digits must be an int from -400 to 400, not {digits!r}")
    return round(number, digits)


def _power(base: float, exponent: float) -> float:
    """``base ** exponent``, refused before it is computed when an int result would be
    over ``MAX_MAGNITUDE`` (about 2**997)."""
    if isinstance(base, int) and isinstance(exponent, int) and exponent >= 0:
        if abs(base) >= 2 and (abs(base).bit_length() - 1) * exponent > 1000:
            raise ValueError(f"the power is over {MAX_MAGNITUDE:g}")
        return base**exponent
    result = float(base) ** float(exponent)
    if isinstance(result, complex):
        raise ValueError("the power is not a real number")
    return result


FUNCTIONS: dict[str, Callable[..., Any]] = {
    **{name: getattr(math, name) for name in MATH_FUNCTIONS},
    "abs": abs,
    "min": min,
    "max": max,
    "int": int,
    "float": float,
    "round": _round,
    "pow": _power,
}
"""What a template may call by name: the math functions, and Python's abs, min, max,
int, float, round and pow on numbers."""

_COMPARISONS: dict[type[ast.cmpop], tuple[str, Callable[[Any, Any], bool]]] = {
    ast.Eq: ("==", lambda a, b: bool(a == b)),
    ast.NotEq: ("!=", lambda a, b: bool(a != b)),
    ast.Lt: ("<", lambda a, b: bool(a < b)),
    ast.LtE: ("<=", lambda a, b: bool(a <= b)),
    ast.Gt: (">", lambda a, b: bool(a > b)),
    ast.GtE: (">=", lambda a, b: bool(a >= b)),
}
_ARITHMETIC: dict[type[ast.operator], tuple[str, Callable[[Any, Any], Any]]] = {
    ast.Add: ("+", lambda a, b: a + b),
    ast.Sub: ("-", lambda a, b: a - b),
    ast.Mult: ("*", lambda a, b: a * b),
    ast.Div: ("/", lambda a, b: a / b),
    ast.FloorDiv: ("//", lambda a, b: a // b),
    ast.Mod: ("%", lambda a, b: a % b),
    ast.Pow: ("**", _power),
}
_OPERATOR_SPELLING = {
    ast.LShift: "<<",
    ast.RShift: ">>",
    ast.BitOr: "|",
    ast.BitXor: "^",
    ast.BitAnd: "&",
    ast.MatMult: "@",
    ast.Invert: "~",
    ast.In: "in",
    ast.NotIn: "not in",
    ast.Is: "is",
    ast.IsNot: "is not",
}
_REFUSED_NAMES = {
    ast.Attribute: "attribute access",
    ast.Subscript: "subscript",
    ast.Lambda: "lambda",
    ast.ListComp: "comprehension",
    ast.SetComp: "comprehension",
    ast.DictComp: "comprehension",
    ast.GeneratorExp: "generator expression",
    ast.NamedExpr: "assignment expression (:=)",
    ast.JoinedStr: "f-string",
    ast.Starred: "starred expression",
    ast.List: "list",
    ast.Tuple: "tuple",
    ast.Set: "set",
    ast.Dict: "dict",
    ast.Yield: "yield",
    ast.YieldFrom: "yield from",
    ast.Await: "await",
}
"""How a refusal names a node it has no rule for (a node absent here is named by its
type): for messages only, since what is accepted is what ``_Interpreter`` has a rule for."""


class _Interpreter:
    """One evaluation of one expression's tree."""

    def __init__(self, text: str, lookup: Lookup) -> None:
        self.text = text
        self.lookup = lookup

    def quote(self, node: ast.AST) -> str:
        return _short(ast.get_source_segment(self.text, node) or ast.dump(node)[:40])

    def refuse(self, what: str, node: ast.AST) -> ExpressionError:
        return ExpressionError(
            f"{what} `{self.quote(node)}` is not allowed in a template expression"
        )

    def checked(self, value: Any, node: ast.AST) -> bool | int | float | str:
        """``value`` if it is a number or text within the bounds."""
        if isinstance(value, str):
            if len(value) > MAX_TEXT_CHARS:
                raise ExpressionError(
                    f"`{self.quote(node)}` is a text of {len(value)} characters, "
                    f"over {MAX_TEXT_CHARS}"
                )
            return value
        if not _is_number(value):
            raise ExpressionError(
                f"`{self.quote(node)}` is {type(value).__name__}, not a number or text"
            )
        if (isinstance(value, float) and not math.isfinite(value)) or abs(value) > MAX_MAGNITUDE:
            raise ExpressionError(f"`{self.quote(node)}` is over {MAX_MAGNITUDE:g}")
        return value

    def value(self, node: ast.AST, depth: int) -> bool | int | float | str:
        if depth > MAX_DEPTH:
            raise ExpressionError(f"the expression is nested over {MAX_DEPTH} deep")
        rule = getattr(self, f"node_{type(node).__name__}", None)
        if rule is None:
            name = _REFUSED_NAMES.get(type(node), type(node).__name__)
            raise self.refuse(name, node)
        try:
            result = rule(node, depth + 1)
        except (ArithmeticError, TypeError, ValueError) as error:
            if isinstance(error, ExpressionError):
                raise
            raise ExpressionError(f"`{self.quote(node)}`: {error}") from None
        return self.checked(result, node)

    def numbers(self, nodes: list[ast.expr], depth: int, what: str) -> list[float]:
        values = [self.value(node, depth) for node in nodes]
        for node, value in zip(nodes, values, strict=True):
            if not _is_number(value):
                raise ExpressionError(f"{what} takes numbers: `{self.quote(node)}` is text")
        return values  # type: ignore[return-value]

    def node_Constant(self, node: ast.Constant, _: int) -> Any:
        if isinstance(node.value, str | int | float):  # bool is an int
            return node.value
        raise ExpressionError(
            f"the constant `{self.quote(node)}` is not allowed in a template expression "
            "(its constants are numbers, True, False and texts)"
        )

    def node_Name(self, node: ast.Name, _: int) -> Any:
        try:
            return self.lookup(node.id)
        except KeyError:
            pass
        if node.id in CONSTANTS:
            return CONSTANTS[node.id]
        if node.id in FUNCTIONS:
            raise ExpressionError(f"`{node.id}` is a function: call it, as `{node.id}(x)`")
        raise NameError(f"name '{node.id}' is not defined")

    def node_Attribute(self, node: ast.Attribute, _: int) -> Any:
        """Only ``math.pi``, ``math.e``, ``math.tau``."""
        if _math_name(node) in CONSTANTS:
            return CONSTANTS[node.attr]
        raise self.refuse("attribute access", node)

    def node_Call(self, node: ast.Call, depth: int) -> Any:
        """A function of ``FUNCTIONS`` by its name, or of ``MATH_FUNCTIONS`` as
        ``math.NAME``, on positional numbers."""
        function = node.func
        name = function.id if isinstance(function, ast.Name) else _math_name(function)
        if name not in FUNCTIONS:
            if not isinstance(function, ast.Name):
                self.value(function, depth)  # a lambda, an attribute... is refused by name
            raise ExpressionError(
                f"calling `{self.quote(function)}` is not allowed in a template expression "
                f"(it may call {', '.join(sorted(FUNCTIONS))})"
            )
        if node.keywords:
            raise self.refuse("keyword argument", node.keywords[0])
        call = getattr(math, name) if isinstance(function, ast.Attribute) else FUNCTIONS[name]
        return call(*self.numbers(node.args, depth, f"`{name}`"))

    def node_BinOp(self, node: ast.BinOp, depth: int) -> Any:
        if type(node.op) not in _ARITHMETIC:
            raise self.refuse(f"the operator `{_OPERATOR_SPELLING[type(node.op)]}` in", node)
        spelling, operation = _ARITHMETIC[type(node.op)]
        left, right = self.value(node.left, depth), self.value(node.right, depth)
        if isinstance(left, str) and isinstance(right, str) and spelling == "+":
            return self.checked(left + right, node)
        if not (_is_number(left) and _is_number(right)):
            texts = "two numbers or two texts" if spelling == "+" else "numbers"
            raise ExpressionError(f"`{self.quote(node)}`: `{spelling}` takes {texts}")
        return operation(left, right)

    def node_UnaryOp(self, node: ast.UnaryOp, depth: int) -> Any:
        operand = self.value(node.operand, depth)
        if isinstance(node.op, ast.Not):
            return not operand
        if isinstance(node.op, ast.USub | ast.UAdd):
            if isinstance(operand, str):
                raise ExpressionError(f"`{self.quote(node)}`: a sign takes a number")
            return -operand if isinstance(node.op, ast.USub) else +operand
        raise self.refuse(f"the operator `{_OPERATOR_SPELLING[type(node.op)]}` in", node)

    def node_BoolOp(self, node: ast.BoolOp, depth: int) -> Any:
        """Python's ``and``/``or``: the deciding operand, the rest unevaluated."""
        for operand in node.values[:-1]:
            result = self.value(operand, depth)
            if bool(result) is isinstance(node.op, ast.Or):
                return result
        return self.value(node.values[-1], depth)

    def node_Compare(self, node: ast.Compare, depth: int) -> bool:
        left = self.value(node.left, depth)
        for op, right_node in zip(node.ops, node.comparators, strict=True):
            if type(op) not in _COMPARISONS:
                raise self.refuse(f"the operator `{_OPERATOR_SPELLING[type(op)]}` in", node)
            spelling, compare = _COMPARISONS[type(op)]
            right = self.value(right_node, depth)
            ordered = spelling not in ("==", "!=")
            if ordered and _is_number(left) != _is_number(right):
                raise ExpressionError(
                    f"`{self.quote(node)}`: `{spelling}` compares two numbers or two texts"
                )
            if not compare(left, right):
                return False
            left = right
        return True

    def node_IfExp(self, node: ast.IfExp, depth: int) -> Any:
        chosen = node.body if self.value(node.test, depth) else node.orelse
        return self.value(chosen, depth)


def _math_name(node: ast.expr) -> str | None:
    """``NAME`` of an exact ``math.NAME`` (a function of ``MATH_FUNCTIONS`` or a constant)."""
    if (
        isinstance(node, ast.Attribute)
        and isinstance(node.value, ast.Name)
        and node.value.id == "math"
        and (node.attr in MATH_FUNCTIONS or node.attr in CONSTANTS)
    ):
        return node.attr
    return None
