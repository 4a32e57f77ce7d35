"""Templates and URDFs that are harmful where a reader trusts them (issue 58), shared by
the service's and the worker's tests: an entity bomb, a name that injects markup, a mesh
at a local path, and a URDF row written as an older server could have stored it."""

from __future__ import annotations

import sqlalchemy as sa

from adservice.models import TrialURDFRow
from tests.picky_template import JOINTED

XACRO = 'xmlns:xacro="http://www.ros.org/wiki/xacro"'
HOSTNAME_MESH = '<mesh filename="/etc/hostname"/>'
"""A mesh the worker's machine has: PyBullet would read it."""


def entity_bomb(padding: int = 0, references: int = 1) -> str:
    """A DTD whose entity ``&b;`` is 80,000 characters, used ``references`` times in a
    ``<gazebo>`` after a comment of ``padding`` characters (expat expands up to 100
    times what it has read: the comment lets the references through)."""
    entities = '<!ENTITY a "' + "x" * 1000 + '"><!ENTITY b "' + "&a;" * 80 + '">'
    return (
        f'<?xml version="1.0"?>\n<!DOCTYPE robot [{entities}]>\n'
        f'<robot name="bomb"><!--{"p" * padding}-->'
        '<link name="base"><visual><geometry><box size="0.1 0.1 0.1"/></geometry></visual>'
        f"</link>{JOINTED}<gazebo>{'&b;' * references}</gazebo></robot>"
    )


def with_base(inside: str, extra: str = "") -> str:
    """A template of the link ``base`` (holding ``inside`` after its collision box) and
    an arm on a revolute joint, ``extra`` after them."""
    return (
        f'<robot name="r" {XACRO}><link name="base"><collision><geometry>'
        f'<box size="0.1 0.1 0.1"/></geometry></collision>{inside}</link>{JOINTED}{extra}</robot>'
    )


INJECTED_NAME = "mesh filename='/etc/hostname'"
"""An element name that writes a mesh element, were it written raw."""
HARMFUL_BETWEEN = with_base(
    '<xacro:if value="${n == 1}"><visual><geometry>'
    f"{HOSTNAME_MESH}</geometry></visual></xacro:if>"
    '<xacro:if value="${n == 3}"><visual><geometry>'
    f'<xacro:element xacro:name="{INJECTED_NAME}"/></geometry></visual></xacro:if>'
)
"""Harmless at n = 0, 2 and 4 (the low, middle and high a study's creation checks); at
n = 1 a visual mesh at a local path, at n = 3 the same mesh written by xacro:element."""
HARMFUL_BETWEEN_SPACE = {
    "type": "template",
    "template": HARMFUL_BETWEEN,
    "params": [{"name": "n", "type": "int", "low": 0, "high": 4}],
}


def store_urdf(database_url: str, trial_id: int, urdf: str) -> None:
    """Replace a trial's stored URDF, as no request can (an older server's row)."""
    engine = sa.create_engine(database_url)
    try:
        with engine.begin() as connection:
            connection.execute(
                sa.update(TrialURDFRow).where(TrialURDFRow.trial_id == trial_id).values(urdf=urdf)
            )
    finally:
        engine.dispose()


def stored_urdfs(database_url: str) -> dict[int, str | None]:
    """Every stored URDF by trial id (None where the trial's expansion failed)."""
    engine = sa.create_engine(database_url)
    try:
        with engine.connect() as connection:
            rows = connection.execute(sa.select(TrialURDFRow.trial_id, TrialURDFRow.urdf))
            return {row.trial_id: row.urdf for row in rows}
    finally:
        engine.dispose()
