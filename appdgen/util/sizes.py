"""Image sizes as written on a command line or in an options file: 'WxH' in pixels."""
from __future__ import annotations

from appdgen.errors import AppdgenError


def parse_size(text: str | None) -> tuple[int, int] | None:
    """'WxH' → (W, H) in pixels; None passes through."""
    if text is None:
        return None
    try:
        w, h = (int(part) for part in text.lower().split("x"))
    except ValueError:
        raise AppdgenError(f"--size {text!r}: expected WIDTHxHEIGHT in pixels, e.g. 348x128") from None
    if w <= 0 or h <= 0:
        raise AppdgenError(f"--size {text!r}: width and height must be positive")
    return w, h
