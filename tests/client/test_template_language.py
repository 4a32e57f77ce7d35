"""The template language (issue 36): ``${...}`` is interpreted by
``adclient.template_expr``, never by Python's eval. What real xacro files use keeps its
values; a corpus of the escape idioms of Python sandboxes is refused, each by the name
of its construct and wherever a template can put it, without one file opened, socket
made, process started, module imported or code object run (a real server's 422 for the issue's
attack: tests/workers/test_templates_e2e.py)."""

from __future__ import annotations

import html
import json
import math
import subprocess
import sys
from collections.abc import Iterator

import pytest

from adclient.template_expr import MAX_DEPTH, MAX_EXPRESSION_CHARS, PARSED_AS
from adclient.templates import XACRO_NS, TemplateError, expand, expand_isolated

REAL_XACRO = f"""<robot name="bot" xmlns:xacro="{XACRO_NS}">
  <xacro:property name="prefix" value="left"/>
  <xacro:property name="width" value="${{length / 2}}"/>
  <xacro:property name="side" value="${{1 if prefix == 'left' else -1}}"/>
  <xacro:macro name="leg" params="name length:=0.4 *origin">
    <link name="${{prefix}}_${{name}}">
      <visual><xacro:insert_block name="origin"/>
        <geometry><cylinder radius="${{max(0.01, length / 20)}}" length="${{length}}"/></geometry>
      </visual>
    </link>
  </xacro:macro>
  <link name="base"><visual><origin rpy="${{pi/2}} ${{radians(90)}} ${{-math.pi / 4}}"/>
    <geometry><box size="${{width}} ${{2**-1}} ${{round(sqrt(2), 3)}}"/></geometry></visual></link>
  <xacro:leg name="thigh"><origin xyz="0 ${{side * width}} 0"/></xacro:leg>
  <xacro:leg name="shin" length="${{length * 0.75}}"><origin xyz="0 0 0"/></xacro:leg>
  <xacro:if value="${{length > 0.3 and prefix != 'right'}}"><link name="long"/></xacro:if>
  <xacro:unless value="${{0 &lt; length &lt; 0.3 or not side}}"><link name="kept"/></xacro:unless>
  <xacro:if value="${{length > 1 and 1 / 0}}"><link name="never"/></xacro:if>
</robot>"""


def test_what_real_xacro_files_use_keeps_its_values() -> None:
    """Properties of properties, a macro's default and block params, ``xacro:if`` and
    ``unless``, ``${pi/2}``, ``radians``, ``math.pi``, text properties joined into
    names, conditional expressions, chained comparisons; ``and`` evaluates no further
    than Python's (no division by zero)."""
    urdf = expand(REAL_XACRO, {"length": 0.5})
    assert f'rpy="{math.pi / 2} {math.radians(90)} {-math.pi / 4}"' in urdf
    assert '<box size="0.25 0.5 1.414"/>' in urdf
    assert '<link name="left_thigh">' in urdf and '<link name="left_shin">' in urdf
    assert '<origin xyz="0 0.25 0"/>' in urdf  # side * width
    assert '<cylinder length="0.4" radius="0.02"/>' in urdf  # the default, not the property
    assert '<cylinder length="0.375" radius="0.01875"/>' in urdf  # length * 0.75, an argument
    assert '<link name="long"/>' in urdf and '<link name="kept"/>' in urdf
    assert "never" not in urdf
    short = expand(REAL_XACRO, {"length": 0.2})
    assert "long" not in short and "kept" not in short


HOSTILE = [
    # scopes the old name check never saw: a lambda's body and its default arguments
    ("(lambda: 1)()", "lambda `lambda: 1`"),
    ("(lambda x=().__class__: x)()", "lambda `lambda x=().__class__: x`"),
    (
        "(lambda: [c for c in ().__class__.__base__.__subclasses__() if c.__name__ == "
        "'_wrap_close'][0].__init__.__globals__['system']('touch pwned'))()",
        "lambda `lambda: [c for c",
    ),
    (
        "(lambda: [c for c in ().__class__.__base__.__subclasses__() if c.__name__ == "
        "'FileLoader'][0].get_data(0, '/etc/hostname'))()",
        "lambda `lambda: [c",
    ),
    (
        "(lambda: [c for c in ().__class__.__base__.__subclasses__() if c.__name__ == "
        "'_wrap_close'][0].__init__.__globals__['__builtins__']['__import__']('socket')"
        ".socket())()",
        "lambda `lambda: [c",
    ),
    ("[c for c in ().__class__.__base__.__subclasses__()]", "comprehension `[c for c"),
    ("(c for c in (1, 2))", "generator expression `(c for c in (1, 2))`"),
    ("(x := 1)", "assignment expression (:=) `x := 1`"),
    ("1 if (lambda: 1) else 2", "lambda `lambda: 1`"),
    ("not (lambda: 1)", "lambda `lambda: 1`"),
    # attribute chains, subscripts, xacro's and Python's symbols
    ("().__class__", "attribute access `().__class__`"),
    ("''.__class__.__mro__[1].__subclasses__()", "attribute access `''.__class__"),
    ("True.__class__", "attribute access `True.__class__`"),
    ("xacro.load_yaml('/etc/hostname')", "attribute access `xacro.load_yaml`"),
    ("xacro.arg('length')", "attribute access `xacro.arg`"),
    ("python.type(1)", "attribute access `python.type`"),
    ("math.__dict__", "attribute access `math.__dict__`"),
    ("math.factorial(10**5)", "attribute access `math.factorial`"),
    ("python['va' + 'rs'](math)", "subscript `python['va' + 'rs']`"),
    ("(1, 2)[0]", "subscript `(1, 2)[0]`"),
    ("__import__('os').system('touch pwned')", "attribute access `__import__('os').system`"),
    # names built at run time, and the builtins that build them
    ("getattr((), '__cla' + 'ss__')", "calling `getattr`"),
    ("vars()", "calling `vars`"),
    ("globals()", "calling `globals`"),
    ("type(1)", "calling `type`"),
    ("__import__('os')", "calling `__import__`"),
    ("eval('1')", "calling `eval`"),
    ("exec('1')", "calling `exec`"),
    ("open('/etc/hostname')", "calling `open`"),
    ("\uff45\uff56\uff41\uff4c('1')", "calling `\uff45\uff56\uff41\uff4c`"),  # fullwidth eval
    ("__builtins__", "name '__builtins__' is not defined"),
    ("max(range(10**12))", "calling `range`"),
    ("(lambda: 0).__code__", "attribute access `(lambda: 0).__code__`"),
    # format strings
    ("'{0.__class__'.format(1)", "attribute access `'{0.__class__'.format`"),
    ("'%s' % 1", "`%` takes numbers"),
    ("f'abc'", "f-string `f'abc'`"),
    # huge values and deep trees, refused before any work
    ("9**9**9", "the power is over 1e+300"),
    ("pow(10, 10**6)", "the power is over 1e+300"),
    ("1 << 10**6", "the operator `<<` in `1 << 10**6`"),
    ("'a' * 10**9", "`*` takes numbers"),
    ("round(1, -10**9)", "round's digits"),
    ("1e400", "`1e400` is over 1e+300"),
    ("-" * MAX_DEPTH + "1", f"nested over {MAX_DEPTH} deep"),
    ("1" * (MAX_EXPRESSION_CHARS + 1), f"over {MAX_EXPRESSION_CHARS}"),
    # other containers and argument forms
    ("(1, 2)", "tuple `(1, 2)`"),
    ("min(*(1, 2))", "starred expression `*(1, 2)`"),
    ("min(1, key=abs)", "keyword argument `key=abs`"),
    ("None", "the constant `None`"),
    ("b'x'", "the constant `b'x'`"),
    ("(yield)", "yield `yield` is not allowed"),
]

SPOTS = {
    "the robot's name": '<robot name="${{{}}}" xmlns:xacro="{}"><link name="a"/></robot>',
    "a property's value": '<robot name="r" xmlns:xacro="{1}"><xacro:property name="p" '
    'value="${{{0}}}"/><link name="${{p}}"/></robot>',
    "xacro:if": '<robot name="r" xmlns:xacro="{1}"><xacro:if value="${{{0}}}"><link name="a"/>'
    "</xacro:if></robot>",
    "a macro's default argument": '<robot name="r" xmlns:xacro="{1}"><xacro:macro name="m" '
    'params="a:=${{{0}}}"><link name="${{a}}"/></xacro:macro><xacro:m/></robot>',
    "a macro's argument": '<robot name="r" xmlns:xacro="{1}"><xacro:macro name="m" params="a">'
    '<link name="${{a}}"/></xacro:macro><xacro:m a="${{{0}}}"/></robot>',
    "a text": '<robot name="r" xmlns:xacro="{1}"><link name="a">${{{0}}}</link></robot>',
}

AUDITED = f"""
import json, sys
from adclient.templates import TemplateError, expand

expand('<robot name="${{1}}"><link name="a"/></robot>', {{}})  # every import done first
events = []
recording = False
HARMLESS = {{
    ("compile", {PARSED_AS!r}),  # the expression's ast.parse
    ("compile", "<unknown>"),  # xacro's is_valid_name: ast.parse of a property's name
}}


def record(event, args):
    if not recording or event == "builtins.id":  # copy.deepcopy asks objects' ids
        return
    if event != "compile" or (event, args[1]) not in HARMLESS:
        events.append([event, repr(args)[:200]])


sys.addaudithook(record)
answers = []
recording = True
for template in json.loads(sys.stdin.read()):
    try:
        expand(template, {{"length": 0.5}})
        answers.append(None)
    except TemplateError as error:
        answers.append(str(error))
recording = False
print(json.dumps({{"answers": answers, "events": events}}))
"""


@pytest.fixture(scope="module")
def audited(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, object]]:
    """The corpus at every spot, expanded in a process of its own (an audit hook cannot
    be removed) that records every audit event but ``builtins.id`` and ``ast.parse``'s,
    in an empty folder."""
    folder = tmp_path_factory.mktemp("hostile")
    templates = [
        spot.format(html.escape(expression), XACRO_NS)
        for expression, _ in HOSTILE
        for spot in SPOTS.values()
    ]
    done = subprocess.run(
        [sys.executable, "-c", AUDITED],
        input=json.dumps(templates),
        capture_output=True,
        text=True,
        cwd=folder,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(done.stdout.splitlines()[-1])
    answers = iter(result["answers"])
    result["answers"] = {
        (expression, where): next(answers) for expression, _ in HOSTILE for where in SPOTS
    }
    result["files"] = sorted(path.name for path in folder.iterdir())
    yield result


@pytest.mark.parametrize(("expression", "construct"), HOSTILE, ids=range(len(HOSTILE)))
def test_each_escape_idiom_is_refused_by_name_wherever_it_is(
    audited: dict[str, dict[tuple[str, str], str | None]], expression: str, construct: str
) -> None:
    for where in SPOTS:
        answer = audited["answers"][(expression, where)]
        assert answer is not None, f"{where}: expanded"
        assert construct in answer, f"{where}: {answer}"


def test_the_corpus_opens_no_file_socket_or_process_and_runs_no_code(
    audited: dict[str, list[object]],
) -> None:
    """Not one audit event while the whole corpus expanded: no ``open``, ``socket.*``,
    ``os.system``, ``subprocess.Popen``, ``import``, ``exec`` (Python's eval runs a code
    object), ``compile`` but the parse; and no file was made."""
    assert audited["events"] == []
    assert audited["files"] == []


def test_a_name_not_in_ascii_is_read_in_the_confined_child_too() -> None:
    """Python's parser imports a module to read such a name, which the confined child
    could not open: the evaluator has it imported before."""
    template = (
        f'<robot name="r" xmlns:xacro="{XACRO_NS}"><link name="${{\u00e9t\u00e9 * 2}}"/></robot>'
    )
    assert '<link name="4"/>' in expand_isolated(template, [{"\u00e9t\u00e9": 2}])[0]


def test_a_refusal_names_the_template_line() -> None:
    template = REAL_XACRO.replace("${length * 0.75}", "${length.real}")
    line = next(n for n, text in enumerate(template.splitlines(), 1) if "length.real" in text)
    with pytest.raises(
        TemplateError,
        match=rf"template: line {line}: attribute access `length.real` is not allowed",
    ):
        expand(template, {"length": 0.5})
