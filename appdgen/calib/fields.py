"""The values a calibration reader takes from a parsed document, each checked with a one-line error, and the
records every format family's reader hands back (Parts for one camera, Found for a recognised file)."""
from __future__ import annotations

import reprlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from appdgen.errors import AppdgenError

Size = tuple[int, int]
#: What a format reader yields for one camera: (image size in the file or None, 3×3 K in pixels, lens model name,
#: its coefficients in the model's order).
Parts = tuple[Size | None, np.ndarray, str, np.ndarray]

_REPR = reprlib.Repr()
_REPR.maxstring = _REPR.maxother = 40
_REPR.maxlevel = 2


@dataclass(frozen=True)
class Found:
    """A recognised file: its format's name, a reader per camera name, the format's default image size, and the
    ROS image topic per camera where the file names one (Kalibr's ``rostopic``)."""

    kind: str
    cameras: dict[str, Callable[[], Parts]]
    default_size: Size | None = None
    topics: dict[str, str] = field(default_factory=dict)


def short(value: Any) -> str:
    """A value as an error message quotes it: repr cut to about 40 characters."""
    return _REPR.repr(value)


def need(mapping: dict[str, Any], key: str, where: str = "") -> Any:
    """mapping[key], or an error naming the missing key."""
    if key not in mapping:
        raise AppdgenError(f"missing key {where + '.' if where else ''}{key}")
    return mapping[key]


def as_mapping(what: str, value: Any) -> dict[str, Any]:
    """value if it is a mapping."""
    if not isinstance(value, dict):
        raise AppdgenError(f"{what}: expected a mapping, got {short(value)}")
    return value


def allowed(what: str, value: Any, names: tuple[str, ...]) -> None:
    """Refuse a model name outside `names`."""
    if value not in names:
        raise AppdgenError(f"{what} {short(value)} is not supported; supported: {', '.join(names)}")


def number(what: str, value: Any) -> float:
    """A finite float from a number or numeric string (YAML 1.1 reads '1e-05' as a string); bools refused."""
    try:
        if isinstance(value, (int, float, str)) and not isinstance(value, bool):
            result = float(value)
            if np.isfinite(result):
                return result
    except (ValueError, OverflowError):
        pass
    raise AppdgenError(f"{what}: expected a finite number, got {short(value)}")


def numbers(what: str, value: Any, counts: tuple[int, ...]) -> np.ndarray:
    """Floats from a list or a whitespace-separated string, whose length must be one of `counts`."""
    items = value.split() if isinstance(value, str) else value
    if not isinstance(items, list):
        raise AppdgenError(f"{what}: expected a list of numbers, got {short(value)}")
    if len(items) not in counts:
        raise AppdgenError(f"{what}: expected {' or '.join(map(str, counts))} numbers, got {len(items)}")
    return np.array([number(f"{what}[{i}]", item) for i, item in enumerate(items)], dtype=float)


def counted(what: str, values: np.ndarray, *counts: int) -> np.ndarray:
    """values if their number is one of `counts`."""
    if values.size not in counts:
        raise AppdgenError(f"{what}: expected {' or '.join(map(str, counts))} numbers, got {values.size}")
    return values


def read_size(what: str, value: Any) -> Size:
    """(width, height) in whole pixels from a 2-number list or string."""
    width, height = numbers(what, value, (2,))
    if not (width.is_integer() and height.is_integer()):
        raise AppdgenError(f"{what}: image size must be whole pixels, got {width:g}x{height:g}")
    return int(width), int(height)


def optional_size(mapping: dict[str, Any], *keys: str) -> Size | None:
    """The image size (pixels) under one [w, h] key or two keys (w, h); None if they are all absent."""
    if not any(k in mapping for k in keys):
        return None
    values = [need(mapping, k) for k in keys]
    return read_size("/".join(keys), values[0] if len(keys) == 1 else values)


def k_matrix(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """The 3×3 camera matrix (pixels) from focal lengths and principal point."""
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
