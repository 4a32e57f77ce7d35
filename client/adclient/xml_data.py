"""XML read as data: a URDF or a template is elements, attributes and text, never a DTD,
an entity or a processing instruction.

Every URDF and template the SDK, the server and the worker read goes through
:func:`parse_xml`: defusedxml's parser, which refuses a ``<!DOCTYPE>`` before any of it
is read (so no entity is ever declared, and none expanded), with processing
instructions refused too; an ``&name;`` that is not one of XML's five is not
well-formed. The text is fed in pieces, so a thread parsing a large document lets the
others run between them. :func:`xml_name_problem` is the name check for what xacro
writes (``xacro:element``, ``xacro:attribute``): a name that is no XML name would put
its text into the output as markup.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from typing import Any

from defusedxml import DefusedXmlException
from defusedxml.ElementTree import DefusedXMLParser

PIECE_CHARS = 1 << 16
"""How much text the parser takes at a time."""
NOT_DATA = (
    "is not allowed (a URDF or template is data: no DTD <!DOCTYPE ...>, entity or "
    "processing instruction <?...?>)"
)
_XML_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_.:-]*")
"""XML's Name production, in ASCII (what URDF and xacro use)."""


class XMLDataError(ValueError):
    """XML that is not well-formed, or not plain data; the message names the line."""


class _Builder:
    """ElementTree's builder, noting the line of each named element, refusing
    processing instructions."""

    def __init__(self, parser: Any) -> None:
        self._tree = ET.TreeBuilder()
        self._expat = parser
        self.lines: dict[tuple[str, str], int] = {}

    def start(self, tag: str, attributes: dict[str, str]) -> ET.Element:
        name = attributes.get("name")
        if name is not None:
            self.lines.setdefault((tag, name), self._expat.CurrentLineNumber)
        return self._tree.start(tag, attributes)

    def end(self, tag: str) -> ET.Element:
        return self._tree.end(tag)

    def data(self, data: str) -> None:
        self._tree.data(data)

    def pi(self, target: str, _: str) -> None:
        raise XMLDataError(
            f"line {self._expat.CurrentLineNumber}: a processing instruction <?{target} ...?> "
            f"{NOT_DATA}"
        )

    def close(self) -> ET.Element:
        return self._tree.close()


def parse_xml(text: str) -> tuple[ET.Element, dict[tuple[str, str], int]]:
    """The document's root element, and the line of each element with a ``name``
    attribute (``(tag, name) -> line``, the first of each); XMLDataError naming the
    line of a DTD, entity or processing instruction, or where the text is not
    well-formed."""
    parser = DefusedXMLParser(target=None, forbid_dtd=True)
    builder = _Builder(parser.parser)
    parser.target = parser._target = builder
    parser.parser.ProcessingInstructionHandler = builder.pi
    try:
        for at in range(0, len(text), PIECE_CHARS):
            parser.feed(text[at : at + PIECE_CHARS])
        root = parser.close()
    except DefusedXmlException as error:
        construct = type(error).__name__.removesuffix("Forbidden").lower()
        raise XMLDataError(
            f"line {parser.parser.CurrentLineNumber}: {_refused(construct)} {NOT_DATA}"
        ) from None
    except ET.ParseError as error:
        line, column = error.position
        reason = str(error).split(":", 1)[0]
        raise XMLDataError(
            f"line {line}, column {column}: not well-formed XML ({reason})"
        ) from None
    return root, builder.lines


def _refused(construct: str) -> str:
    return {
        "dtd": "a DOCTYPE",
        "entities": "an entity declaration",
        "externalreference": "an external reference",
    }.get(construct, construct)


def plain_data_problem(text: str) -> str | None:
    """Where a text declares a DTD or entity or holds a processing instruction, said
    with its line; None when it holds none (also when it is not well-formed: that is
    for whoever reads it next to say)."""
    try:
        parse_xml(text)
    except XMLDataError as error:
        return None if "not well-formed XML" in str(error) else str(error)
    return None


def xml_name_problem(name: str) -> str | None:
    """Why ``name`` is no XML name (as an element's or attribute's); None when it is."""
    if _XML_NAME.fullmatch(name):
        return None
    return f"{name[:80]!r} is not an XML name (letters, digits, _ . : -, not a digit first)"
