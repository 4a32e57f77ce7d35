"""Issue 58: a template and every URDF are XML as data. A DTD, an entity or a processing
instruction is refused by name and line before anything expands or builds; the names
xacro writes from values are XML names; visual shapes are checked as collision shapes
are; reading a URDF costs time linear in its links; each point of an expansion is
checked alone, in the child."""

from __future__ import annotations

import gc
import time

import pytest

from adclient.schemas import BoxParam
from adclient.templates import (
    ByteLimit,
    TemplateError,
    check_template,
    expand,
    expand_checked,
    template_problems,
)
from adclient.urdf_model import URDFModelError, read_urdf

ARM = (
    '<link name="arm"><collision><geometry><box size="0.1 0.1 0.1"/></geometry></collision>'
    "</link>"
    '<joint name="j" type="revolute"><parent link="base"/><child link="arm"/>'
    '<axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>'
)
BASE = '<link name="base"><collision><geometry><box size="${s} 0.1 0.1"/></geometry></collision>'


def robot(extra: str = "") -> str:
    """A template of a base link (its size the param ``s``) and an arm, and ``extra``."""
    return (
        f'<robot name="r" xmlns:xacro="http://www.ros.org/wiki/xacro">{BASE}</link>{ARM}'
        f"{extra}</robot>"
    )


PARAMS = [BoxParam(name="s", low=0.1, high=0.2)]
BOMB = (
    '<?xml version="1.0"?>\n'
    '<!DOCTYPE robot [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">\n'
    '<!ENTITY c "&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;">]>\n'
)
"""A DTD whose entity ``&c;`` is a thousand characters (small: the code before issue 58
expanded it, and this must not cost that code much either)."""


def test_a_template_declaring_entities_is_refused_naming_the_doctype_and_its_line() -> None:
    template = BOMB + robot("<gazebo>&c;</gazebo>")
    problems = template_problems(template, ["s"])
    assert problems[0].startswith("template: line 2: a DOCTYPE is not allowed"), problems
    with pytest.raises(TemplateError, match="line 2: a DOCTYPE is not allowed"):
        expand(template, {"s": 0.1})
    with pytest.raises(TemplateError, match="DOCTYPE"):
        check_template(template, PARAMS)
    # a DOCTYPE without entities is refused alike: nothing is read before the root
    with pytest.raises(TemplateError, match="line 1: a DOCTYPE"):
        expand("<!DOCTYPE robot>" + robot(), {"s": 0.1})


def test_a_processing_instruction_in_a_template_is_refused_naming_its_line() -> None:
    template = robot("\n<?php system('id'); ?>")
    with pytest.raises(TemplateError, match=r"line 2: a processing instruction <\?php"):
        expand(template, {"s": 0.1})
    assert template_problems(template, ["s"])[0].startswith("template: line 2: a processing")


@pytest.mark.parametrize(
    ("extra", "named"),
    [
        pytest.param(
            '<xacro:element xacro:name="${kind}"/>', "an element's name", id="xacro:element"
        ),
        pytest.param(
            '<gazebo><xacro:attribute name="${kind}" value="1"/></gazebo>',
            "<gazebo>: an attribute's name",
            id="xacro:attribute",
        ),
    ],
)
def test_names_xacro_writes_from_values_are_xml_names(extra: str, named: str) -> None:
    """At a value that is markup, the name is refused (before issue 58 xacro wrote it
    raw: the value's markup and entity references were the URDF's)."""
    template = (
        '<robot name="r" xmlns:xacro="http://www.ros.org/wiki/xacro">'
        f'<xacro:property name="kind" value="gazebo"/>{BASE}</link>{ARM}{extra}</robot>'
    )
    assert "gazebo" in expand(template, {"s": 0.1})  # a name is fine
    injected = "link name='evil'/><link name='x"
    with pytest.raises(TemplateError, match=f'{named} "{injected}" is not an XML name'):
        expand(template, {"s": 0.1, "kind": injected})


def test_the_expansion_is_its_root_alone() -> None:
    urdf = expand("<!-- a licence -->\n" + robot(), {"s": 0.1})
    assert urdf.startswith('<?xml version="1.0" ?>\n<robot name="r"')


def test_read_urdf_refuses_a_dtd_and_a_processing_instruction_and_expands_no_entity() -> None:
    urdf = expand(robot(), {"s": 0.1})
    body = urdf.split("\n", 1)[1]
    assert read_urdf(urdf).links.keys() == {"base", "arm"}
    bombed = BOMB + body.replace('name="r"', 'name="&c;"')
    with pytest.raises(URDFModelError, match="line 2: a DOCTYPE is not allowed"):
        read_urdf(bombed)
    with pytest.raises(URDFModelError, match=r"not well-formed XML \(undefined entity\)"):
        read_urdf(body.replace('name="r"', 'name="&c;"'))  # no DTD: an unknown entity
    with pytest.raises(URDFModelError, match="processing instruction <\\?evil"):
        read_urdf(body.replace("</robot>", "<?evil?></robot>"))


@pytest.mark.parametrize(
    ("visual", "named"),
    [
        pytest.param(
            '<visual><geometry><mesh filename="/etc/hostname"/></geometry></visual>',
            r"its geometry is <mesh> \(in a <visual>\)",
            id="visual mesh",
        ),
        pytest.param(
            '<visual><geometry><box size="1 1 1"/></geometry><material name="m">'
            '<texture filename="/etc/hostname"/></material></visual>',
            "its material has <texture>",
            id="texture",
        ),
    ],
)
def test_visual_shapes_are_checked_as_collision_shapes_are(visual: str, named: str) -> None:
    """A link with collisions had its visuals unread, so a mesh (a file on the worker)
    went on to PyBullet; now a visual is a primitive too, and a material a colour."""
    urdf = expand(robot(), {"s": 0.1}).replace("</link>", visual + "</link>", 1)
    with pytest.raises(URDFModelError, match=named):
        read_urdf(urdf)
    template = robot().replace("</link>", visual + "</link>", 1)
    with pytest.raises(TemplateError, match=named):
        check_template(template, PARAMS)


def chain(links: int) -> str:
    """A robot of ``links`` links in a chain, all fixed to the next but the last joint."""
    parts = [
        f'<link name="l{i}"><collision><geometry><box size="1 1 1"/></geometry></collision></link>'
        for i in range(links)
    ]
    for i in range(1, links):
        kind = "revolute" if i == links - 1 else "fixed"
        parts.append(
            f'<joint name="j{i}" type="{kind}"><parent link="l{i - 1}"/><child link="l{i}"/>'
            '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint>'
        )
    return f'<robot name="chain">{"".join(parts)}</robot>'


def fastest(text: str, runs: int) -> float:
    """The fastest of ``runs`` reads, Python's cyclic collector off (its passes over
    every object alive are no cost of the reading's own)."""
    seconds = []
    gc.collect()
    gc.disable()
    try:
        for _ in range(runs):
            started = time.perf_counter()
            read_urdf(text)
            seconds.append(time.perf_counter() - started)
    finally:
        gc.enable()
    return min(seconds)


def test_reading_a_urdf_costs_time_linear_in_its_links() -> None:
    """8,000 fixed links in a chain took 10 s: each link's walk to the root. Now one
    walk from the root: 8 times the links cost about 8 to 10 times as long here (64
    times, were it quadratic: 66 before issue 58); the fastest of a few runs of each,
    measured here against each other."""
    small, large = chain(1000), chain(8000)
    assert len(read_urdf(large).links) == 8000
    ratio = fastest(large, 3) / fastest(small, 5)
    assert ratio < 32, ratio


def test_each_point_is_checked_alone_in_the_child() -> None:
    """One child for the points, each URDF checked as the creation checks are (a robot,
    the task's links, its bytes, the batch's bytes): a point that fails is refused with
    why, the others kept."""
    template = robot('<gazebo reference="${n}"/>')
    points = [
        {"s": 0.1, "n": "x"},  # fine
        {"s": -0.1, "n": "x"},  # builds no robot: a negative size
        {"s": 0.1, "n": "x" * 3500},  # one URDF over 3,000 bytes
        {"s": 0.2, "n": "x"},  # fine
        {"s": 0.1, "n": "x" * 2000},  # within 3,000 alone, not with those before it
    ]
    results = expand_checked(
        template,
        points,
        links=[("lifted_link", "arm")],
        max_bytes=ByteLimit(3000, "the limit of 3,000 bytes (A)"),
        max_total_bytes=ByteLimit(3500, "the limit of 3,500 bytes (B)"),
    )
    assert [result.urdf is not None for result in results] == [True, False, False, True, False]
    assert "its <box> has a size that is not above 0" in results[1].message()
    assert results[2].message().startswith("template, expanded: it is ")
    assert results[2].message().endswith("over the limit of 3,000 bytes (A)")
    assert results[4].message().endswith("over the limit of 3,500 bytes (B)")
    missing = expand_checked(template, points[:1], links=[("lifted_link", "hand")])
    assert (
        missing[0]
        .message()
        .startswith("task.options.lifted_link: the template's robot has no link 'hand'")
    )
