"""studies.fieldresponse: its helpers against values known by construction."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from appdgen.detect.edges import EdgePoints
from studies.fieldresponse import curvature_gap, unmapped


def bent(curvatures: list[float], shift: float = 0.0) -> SimpleNamespace:
    """One frame's evidence: horizontal 200 px segments, one per curvature (px per (100 px)²), stacked in v."""
    s = np.arange(-100.0, 100.0 + 1e-9, 4.0)
    segs = len(curvatures)
    seg = np.repeat(np.arange(segs), s.size)
    ss = np.tile(s, segs)
    e = np.concatenate([k * (s / 100) ** 2 for k in curvatures])
    v0 = 50.0 * np.arange(segs)
    u, v = ss + 300.0 + shift, v0[seg] + e
    normal = np.tile([0.0, 1.0], (segs, 1))
    centre = np.column_stack([np.full(segs, 300.0 + shift), v0])
    points = EdgePoints(u, v, ss, e, seg, normal, centre, np.full(segs, 200.0), np.ones(segs))
    return SimpleNamespace(points=points, segments=segs)


def test_curvature_gap_matches_segments_and_measures_their_curvature_difference() -> None:
    a = [bent([0.1, -0.3, 0.5]), bent([0.2, 0.0, -0.1])]
    same = curvature_gap(a, a)
    assert same[0] == pytest.approx(1.0) and same[1] == pytest.approx(0.0, abs=1e-9) and same[2] == 6
    b = [bent([0.15, -0.25, 0.55], shift=2.0), bent([0.25, 0.05, -0.05], shift=2.0)]  # 2 px along: still matched
    corr, gap, n = curvature_gap(a, b)
    assert n == 6 and gap == pytest.approx(0.05, rel=1e-6) and corr > 0.99
    far = [bent([0.1, -0.3, 0.5], shift=10.0), bent([0.2, 0.0, -0.1], shift=10.0)]  # centres 10 px apart
    corr, gap, n = curvature_gap(a, far)
    assert n == 0 and np.isnan(corr) and np.isnan(gap)


def test_unmapped_prefers_the_reading_before_the_camera_map() -> None:
    assert unmapped({"appd": 0.4, "sd": 0.2, "raw": 0.3, "raw_sd": 0.1}) == (0.3, 0.1)
    assert unmapped({"appd": 0.4, "sd": 0.2, "raw": None, "raw_sd": None}) == (0.4, 0.2)
    assert unmapped({"appd": 0.4, "sd": 0.2}) == (0.4, 0.2)
