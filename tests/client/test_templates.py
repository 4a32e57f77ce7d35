"""Templates (issue 28): a user's xacro or URDF expands at the params' values, is read
into the robot a worker builds, and every way it can be wrong is refused by name (and
line), in a child process that a hostile template cannot hang or exhaust."""

from __future__ import annotations

import json
import resource
import signal
import subprocess
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import pytest

from adclient import templates
from adclient.importing import read_import
from adclient.schemas import BoxParam, TemplateSpace
from adclient.templates import (
    TemplateError,
    check_template,
    expand,
    expand_isolated,
    template_problems,
)
from adclient.urdf_model import URDFModelError, read_urdf

ARM = (
    Path(__file__).resolve().parents[2] / "examples" / "templates" / "arm.urdf.xacro"
).read_text()
PARAMS = [
    BoxParam(name="upper_length", low=0.1, high=0.5),
    BoxParam(name="fore_length", low=0.1, high=0.5),
    BoxParam(name="hand_radius", low=0.02, high=0.08),
]
VALUES = {"upper_length": 0.35, "fore_length": 0.2, "hand_radius": 0.04}

ROBOT = """<robot name="r">
  <link name="a"><collision><geometry><box size="0.1 0.1 0.1"/></geometry></collision></link>
  <link name="b"><collision><geometry>
    <cylinder radius="0.02" length="${b_length}"/>
  </geometry></collision></link>
  <joint name="j" type="revolute"><parent link="a"/><child link="b"/>
    <limit lower="-1" upper="1" effort="2" velocity="3"/></joint>
</robot>"""


def line_of(text: str) -> int:
    """The line of the example template where ``text`` first appears."""
    return next(n for n, line in enumerate(ARM.splitlines(), start=1) if text in line)


FOREARM_LINE = line_of('length="${fore}"')
LINES = {name: line_of(f'name="{name}"') for name in ("wrist", "elbow", "shoulder", "hand")}


def _cylinder_lengths(urdf: str) -> dict[str, float]:
    return {
        link.get("name", ""): float(cylinder.get("length", "nan"))
        for link in ElementTree.fromstring(urdf).iter("link")
        for cylinder in link.iter("cylinder")
    }


def test_args_and_properties_take_the_values() -> None:
    """upper_length and fore_length are xacro args, hand_radius a declared property:
    the expanded URDF has the values, not the template's defaults."""
    urdf = expand(ARM, VALUES)
    lengths = _cylinder_lengths(urdf)
    assert lengths["upper_arm"] == 0.35
    assert lengths["forearm"] == 0.2
    spheres = [float(s.get("radius", "nan")) for s in ElementTree.fromstring(urdf).iter("sphere")]
    assert spheres == [0.04, 0.04]  # visual and collision
    elbow = next(j for j in ElementTree.fromstring(urdf).iter("joint") if j.get("name") == "elbow")
    assert elbow.find("origin").get("xyz") == "0.35 0 0"  # type: ignore[union-attr]
    # a plain URDF with ${name} and no xacro namespace: the property is defined for it
    assert _cylinder_lengths(expand(ROBOT, {"b_length": 0.7}))["b"] == 0.7


def test_the_isolated_expansion_is_the_same_robot() -> None:
    points = [VALUES, {**VALUES, "upper_length": 0.1}]
    assert expand_isolated(ARM, points) == [expand(ARM, point) for point in points]
    model = read_urdf(expand(ARM, VALUES))
    assert model.root == "foot"
    assert [(j.name, j.kind) for j in model.joints] == [
        ("shoulder", "revolute"),
        ("elbow", "revolute"),
        ("wrist", "fixed"),
    ]
    assert [j.name for j in model.driven] == ["shoulder", "elbow"]
    rod = 1200 * 3.141592653589793 * 0.025**2
    hand = 1200 * 4 / 3 * 3.141592653589793 * 0.04**3
    assert model.mass == pytest.approx(0.6 + rod * (0.35 + 0.2) + hand, rel=1e-12)


@pytest.mark.parametrize(
    ("construct", "named"),
    [
        ('<xacro:include filename="/etc/passwd"/>', "xacro:include"),
        ('<link name="$(find my_pkg)"/>', "$(find ...)"),
        ('<link name="$(env HOME)"/>', "$(env ...)"),
        ('<link name="$(optenv AD_TOKEN none)"/>', "$(env ...)"),
        ("<link name=\"${xacro.load_yaml('/etc/hosts')}\"/>", "load_yaml"),
        ("<link name=\"$(eval open('/etc/hostname').read())\"/>", "$(eval ...)"),
        ('<link name="$(cwd)"/>', "$(cwd)"),
    ],
)
def test_a_template_that_reads_files_or_the_environment_is_refused(construct, named) -> None:
    template = ROBOT.replace("</robot>", construct + "</robot>")
    problems = template_problems(template, ["b_length"])
    assert len(problems) == 1 and named in problems[0]
    # the same text in a comment is only a comment
    assert (
        template_problems(ROBOT.replace("</robot>", f"<!-- {construct} --></robot>"), ["b_length"])
        == []
    )
    with pytest.raises(TemplateError, match="is not allowed"):
        check_template(template, [BoxParam(name="b_length", low=0.1, high=1)])


@pytest.mark.parametrize(
    ("construct", "named"),
    [
        # spelt so that no text check sees them: the hardened xacro still refuses them
        ("<link name=\"$(${'ev' + 'al'} 1 + 1)\"/>", r"\$\(eval \.\.\.\) is not allowed"),
        ("<link name=\"$(${'en' + 'v'} HOME)\"/>", r"\$\(env \.\.\.\) is not allowed"),
        ("<link name=\"$(${'cw' + 'd'})\"/>", r"\$\(cwd \.\.\.\) is not allowed"),
        ("<link name=\"${xacro['load_' + 'yaml']('/etc/hosts')}\"/>", r"subscript `xacro\["),
        ("<link name=\"${python['va' + 'rs'](math)}\"/>", r"subscript `python\["),
        (
            "<xacro:element xacro:name=\"${'xacro:incl' + 'ude'}\" filename=\"/etc/passwd\"/>",
            "xacro:include is not allowed",
        ),
    ],
)
def test_the_expanding_xacro_refuses_what_the_text_check_cannot_see(construct, named) -> None:
    template = ROBOT.replace("<robot", '<robot xmlns:xacro="http://www.ros.org/wiki/xacro"')
    template = template.replace("</robot>", construct + "</robot>")
    assert template_problems(template, ["b_length"]) == []  # the text check is fooled
    with pytest.raises(TemplateError, match=named):
        expand_isolated(template, [{"b_length": 0.5}])


def test_a_param_the_template_never_uses_is_named() -> None:
    params = [*PARAMS, BoxParam(name="elbow_effort", low=1, high=5)]
    with pytest.raises(TemplateError, match="'elbow_effort' is not used by the template"):
        check_template(ARM, params)
    assert template_problems(ARM, [param.name for param in PARAMS]) == []


def test_the_text_check_is_one_pass() -> None:
    """A megabyte of unclosed openings (a rescanning pattern took minutes on this;
    ``_pieces`` scans once): a name inside one is no use of a param, one closed before
    them is."""
    for opening, use in (("<!--", "${c}"), ("${", "${c}"), ("$(", "$(arg c)"), ("<x:arg ", "${c}")):
        flood = opening * (1_000_000 // len(opening))
        unused = template_problems(ROBOT + flood + use.replace("}", ""), ["b_length", "c"])
        assert len(unused) == 1 and "'c' is not used" in unused[0]
        assert template_problems(ROBOT + use + flood, ["b_length", "c"]) == []


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (("</robot>", "</robt>"), r"template: line \d+, column \d+: mismatched tag"),
        (
            ('length="${fore}"', 'length="${forarm}"'),
            f"template: line {FOREARM_LINE}: NameError: name 'forarm'",
        ),
        (
            ('type="fixed"', 'type="floating"'),
            rf"joint 'wrist' \(line {LINES['wrist']}\): type 'floating'",
        ),
        (
            ('upper="2.6" effort="2"', 'upper="-2.7" effort="2"'),
            rf"joint 'elbow' \(line {LINES['elbow']}\): its limit needs lower < upper",
        ),
        (
            ('effort="4"', 'effort="0"'),
            rf"joint 'shoulder' \(line {LINES['shoulder']}\): its limit needs effort > 0",
        ),
        (
            (
                '<sphere radius="${hand_radius}"/></geometry></collision>',
                '<mesh filename="hand.stl"/></geometry></collision>',
            ),
            rf"link 'hand' \(line {LINES['hand']}\): its geometry is <mesh>",
        ),
        (
            ('<child link="hand"/>', '<child link="palm"/>'),
            "joint 'wrist' .*: its child 'palm' is no link",
        ),
        (('<parent link="foot"/>', '<parent link="hand"/>'), "the links form no tree"),
    ],
)
def test_a_template_that_does_not_expand_to_a_robot_is_named(change, message) -> None:
    with pytest.raises(TemplateError, match=message):
        check_template(ARM.replace(*change), PARAMS)


def test_the_check_runs_at_each_end_of_the_params() -> None:
    """A template that breaks only at its params' highs is caught there."""
    broken_high = ARM.replace(
        'lower="-0.3" upper="2.6"', 'lower="${upper - 0.45}" upper="${0.5 - upper}"'
    )
    with pytest.raises(TemplateError, match="expanded at the params' highs: joint 'shoulder'"):
        check_template(broken_high, PARAMS)


def test_a_task_link_the_robot_lacks_is_named() -> None:
    check_template(ARM, PARAMS, [("distal_link", "forearm")])
    with pytest.raises(
        TemplateError,
        match=r"lifted_link: .* no link 'b' \(its links: foot, upper_arm, forearm, hand\)",
    ):
        check_template(ARM, PARAMS, [("lifted_link", "b")])


JOINED = '<link name="a"/><link name="b"/><joint name="j" type="{}"><parent link="a"/>{}</joint>'
CYLINDER = '<collision><geometry><cylinder radius="0" length="1"/></geometry></collision>'


@pytest.mark.parametrize(
    ("structure", "message"),
    [
        ('<link name="a"/><link name="a"/>', "two links of that name"),
        ('<link name="a"/><link name="b"/>', "2 links have no parent"),
        (JOINED.format("fixed", '<child link="b"/>'), "no joint to drive"),
        (JOINED.format("revolute", '<child link="b"/>'), "a revolute joint needs <limit"),
        (f'<link name="a">{CYLINDER}</link>', "size that is not above 0"),
        ('<link name="a"><inertial><mass value="nan"/></inertial></link>', "is not finite"),
    ],
)
def test_read_urdf_names_what_no_robot_can_be(structure, message) -> None:
    with pytest.raises(URDFModelError, match=message):
        read_urdf(f"<robot name='r'>{structure}</robot>")


def doubling(levels: int, body: str) -> str:
    """A template whose macro ``m{k}`` calls ``m{k-1}`` twice, ``m0`` being ``body``:
    ``2**levels`` copies of it, the work (and, with ``${...}`` in a text, the memory)
    no expression can make (its values are bounded)."""
    calls = [body] + [f"<xacro:m{k - 1}/><xacro:m{k - 1}/>" for k in range(1, levels + 1)]
    macros = "".join(
        f'<xacro:macro name="m{k}" params="">{call}</xacro:macro>' for k, call in enumerate(calls)
    )
    return f'<robot name="r" xmlns:xacro="{templates.XACRO_NS}">{macros}<xacro:m{levels}/></robot>'


BUSY_TEMPLATE = doubling(40, "")


def test_a_hostile_template_cannot_exhaust_or_hang_the_expanding_process(monkeypatch) -> None:
    """Memory past EXPAND_MEMORY and CPU past EXPAND_SECONDS end the child, not the
    caller: a TemplateError each, and this process unharmed."""
    monkeypatch.setattr(templates, "EXPAND_MEMORY", 128 << 20)  # reached in about a second
    with pytest.raises(TemplateError, match="MemoryError"):
        expand_isolated(doubling(30, "<a>${1}" + "x" * 100_000 + "</a>"), [{}])
    monkeypatch.setattr(templates, "EXPAND_SECONDS", 2)
    # the CPU limit ends a busy child (a starved one meets the clock a second later)
    with pytest.raises(TemplateError, match=r"took over (2 s of CPU|3 s)"):
        expand_isolated(BUSY_TEMPLATE, [{}])


def test_the_expanding_child_ends_itself_with_sigxcpu_at_its_cpu_limit_and_dumps_no_core(
    monkeypatch, tmp_path: Path
) -> None:
    """The child's CPU limit sends SIGXCPU, read as "took over N s of CPU" (a hard limit
    equal to the soft one would SIGKILL it, an unexplained "exit -9"), and the core that
    SIGXCPU dumps is never written, even where the caller's limits allow one."""
    monkeypatch.setattr(templates, "EXPAND_SECONDS", 1)
    command, env = templates.child_command()
    request = json.dumps({"template": BUSY_TEMPLATE, "points": [{}]}).encode()

    def allow_cores() -> None:
        _, hard = resource.getrlimit(resource.RLIMIT_CORE)
        resource.setrlimit(resource.RLIMIT_CORE, (hard, hard))

    done = subprocess.run(
        command,
        input=request,
        capture_output=True,
        env=env,
        cwd=tmp_path,
        preexec_fn=allow_cores,
        timeout=60,
    )
    assert done.returncode == -signal.SIGXCPU, done.stderr.decode(errors="replace")[-300:]
    assert list(tmp_path.iterdir()) == []


def test_a_csv_is_read_in_a_template_s_param_types() -> None:
    """Trials imported into a template study: a categorical cell stays its choice (text
    "02", which a reader without the space takes for the number 2), an int cell an int."""
    space = TemplateSpace(
        type="template",
        template=ROBOT.replace('length="${b_length}"', 'length="${b_length * n}"').replace(
            '<robot name="r">', '<robot name="r_${finish}">'
        ),
        params=[
            BoxParam(name="b_length", low=0.1, high=1.0),
            BoxParam(name="n", type="int", low=1, high=3),
            BoxParam(name="finish", type="categorical", choices=["01", "02"]),
        ],
    ).model_dump(mode="json")
    plan = read_import("b_length,n,finish,value\n0.5,2,02,1.5\n", format="csv", space=space)
    (trial,) = plan.trials
    assert trial.params == {"b_length": 0.5, "n": 2, "finish": "02"}  # not the number 2
