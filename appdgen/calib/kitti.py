"""KITTI raw ``calib_cam_to_cam.txt``: ``S_xx`` (size), ``K_xx`` (3×3, row-major), ``D_xx`` (k1 k2 p1 p2 k3).

The full published file or the reduced S/K/D-only layout, keys in any order, other keys ignored; model radtan.
Cameras are the two-digit suffixes present (``'00'`` … ``'03'``).
"""
from __future__ import annotations

import re
from functools import partial

from appdgen.calib.calibration import DEFAULT_MODEL
from appdgen.calib.fields import Found, Parts, need, numbers, read_size
from appdgen.errors import AppdgenError

_KITTI_KEY = re.compile(r"^[ \t]*[SKD]_([0-9]{2})[ \t]*:", re.MULTILINE)


def recognise(text: str) -> Found | None:
    """A KITTI calib_cam_to_cam.txt split into its cameras (the xx of S_xx/K_xx/D_xx keys), or None."""
    if not _KITTI_KEY.search(text):
        return None
    lines: dict[str, str] = {}
    for line in text.splitlines():
        key, colon, value = line.partition(":")
        if colon:
            if key.strip() in lines:
                raise AppdgenError(f"duplicate key {key.strip()}")
            lines[key.strip()] = value
    names = sorted({m.group(1) for m in _KITTI_KEY.finditer(text)})
    return Found("KITTI", {n: partial(_camera, lines, n) for n in names})


def _camera(lines: dict[str, str], n: str) -> Parts:
    """Size, K and radtan coefficients of KITTI camera n from its S_n, K_n and D_n lines."""
    s = f"S_{n}"
    K = numbers(f"K_{n}", need(lines, f"K_{n}"), (9,)).reshape(3, 3)
    D = numbers(f"D_{n}", need(lines, f"D_{n}"), (4, 5))
    return (read_size(s, lines[s]) if s in lines else None), K, DEFAULT_MODEL, D
