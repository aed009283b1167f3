"""The text of a calibration file parsed as YAML (OpenCV's dialects included), JSON or OpenCV FileStorage XML:
syntax only; which format a document is, each format family's module says."""
from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from typing import Any

import yaml

from appdgen.errors import AppdgenError


class _OpenCVLoader(yaml.SafeLoader):
    """A SafeLoader that reads OpenCV's ``!!opencv-matrix`` (and other ``!!opencv-*``) nodes as mappings."""


_OpenCVLoader.add_multi_constructor(
    "tag:yaml.org,2002:opencv-", lambda loader, _suffix, node: loader.construct_mapping(node, deep=True)
)


def parse_yaml(text: str) -> Any:
    """The YAML document, after dropping OpenCV 4's non-standard ``%YAML:1.0`` first line."""
    if text.startswith("%YAML:"):
        text = "\n" + text.partition("\n")[2]
    try:
        return yaml.load(text, Loader=_OpenCVLoader)  # noqa: S506 - a SafeLoader subclass
    except Exception as exc:  # PyYAML leaks KeyError ('!!bool x'), ValueError (bad dates), RecursionError…
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or f"{type(exc).__name__}: {exc}"
        raise AppdgenError(f"invalid YAML: {problem}{where}") from None


def parse_json(text: str) -> Any:
    """The JSON document."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise AppdgenError(f"invalid JSON: {exc.msg} at line {exc.lineno}, column {exc.colno}") from None
    except (ValueError, RecursionError) as exc:  # over-long integers, too deep nesting
        raise AppdgenError(f"invalid JSON: {type(exc).__name__}: {exc}") from None


def parse_xml(text: str) -> dict[str, Any]:
    """OpenCV FileStorage XML as {tag: text, or {child tag: text}}: the two levels a calibration uses."""
    if "<!DOCTYPE" in text or "<!ENTITY" in text:
        raise AppdgenError("XML with a DTD or entities is not supported")
    try:
        root = ET.fromstring(text.encode("utf-8"))
    except (ET.ParseError, ValueError, LookupError) as exc:  # LookupError/ValueError: odd encoding declarations
        raise AppdgenError(f"invalid XML: {exc}") from None
    return {c.tag: {g.tag: _xml_text(g) for g in c} if len(c) else _xml_text(c) for c in root}


def _xml_text(element: ET.Element) -> str:
    """An element's text, stripped."""
    return (element.text or "").strip()
