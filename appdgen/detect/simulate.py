"""A belief's evidence simulated from the evidence of frames rectified under the camera's true calibration (REF),
without rectifying or detecting again: the same scene seen through belief b's rectification shows the raw pixel
that REF's output pixel p shows at b's output pixel q = K̂b·undistort_b(M̂ref(p)) (geometry.bend.output_warp with
the roles swapped). Each edge point is moved there and each segment's line, normal, arc positions and offsets are
recomputed from the moved points (the solve removes each segment's own line, so the line only needs to be close).
Points that leave b's output image are dropped, as are segments left with too few points.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from appdgen.calib.calibration import Calibration
from appdgen.detect.edges import EdgeParams, EdgePoints, collect_points
from appdgen.detect.model import belief_crop
from appdgen.errors import AppdgenError
from appdgen.geometry.appd import appd
from appdgen.geometry.bend import output_warp
from appdgen.sampling.reach import UnreachableError
from appdgen.sampling.sampler import Sampler


def warp_points(points: EdgePoints, reference: Calibration, reference_crop, belief: Calibration, belief_crop,
                min_points: int = EdgeParams().min_points) -> EdgePoints:
    """REF-rectified edge points as belief b's rectification shows them (belief output px)."""
    if points.segments == 0:
        return points
    u, v = output_warp(belief, belief_crop, reference, reference_crop, points.u, points.v)
    w, h = belief.size
    keep = np.isfinite(u) & np.isfinite(v) & (u >= 2) & (u <= w - 3) & (v >= 2) & (v <= h - 3)
    u, v = np.where(keep, u, 0.0), np.where(keep, v, 0.0)
    sg, ns, wk = points.seg, points.segments, keep.astype(float)
    cnt = np.maximum(np.bincount(sg, wk, ns), 1.0)
    du, dv = u - (np.bincount(sg, wk * u, ns) / cnt)[sg], v - (np.bincount(sg, wk * v, ns) / cnt)[sg]
    # each segment's direction: the leading axis of its moved points' scatter, signed as the old direction
    suu, svv, suv = (np.bincount(sg, wk * a * b, ns) for a, b in ((du, du), (dv, dv), (du, dv)))
    angle = 0.5 * np.arctan2(2 * suv, suu - svv)
    n = np.column_stack([-np.sin(angle), np.cos(angle)])
    n *= np.where((n * points.normal).sum(1) < 0, -1.0, 1.0)[:, None]
    s = du * n[sg, 1] - dv * n[sg, 0]  # along t = (n_y, −n_x)
    e = du * n[sg, 0] + dv * n[sg, 1]
    return collect_points(u - e * n[sg, 0], v - e * n[sg, 1], s, e, sg, n, points.contrast, keep, min_points)


def warp_evidence(evidence: Sequence, reference: Calibration, reference_crop, belief: Calibration, belief_crop
                  ) -> list:
    """Each frame's Evidence (under REF) as belief b's rectification would show it."""
    out = []
    for ev in evidence:
        pts = warp_points(ev.points, reference, reference_crop, belief, belief_crop)
        out.append(replace(ev, segments=pts.segments, points=pts, seconds=0.0))
    return out


#: Simulated beliefs a baseline reads on its own frames to learn the camera's map (each builds its field model).
SIMULATED = 12
MAP_SEED = 4243  # simulated belief i is Sampler(REF).draw(MAP_SEED, i): what `appdgen build` makes from REF
FOLDS = 2  # the good frames in contiguous parts: each part is read against the baseline of the others
KINDS = ("identity", "shift", "linear")  # the maps tried, simplest first
#: A map replaces a simpler one only when its held-out error is lower by this many standard errors (over beliefs):
#: with a dozen simulated beliefs a smaller gain is as often chance (the desk's shift of +0.11 % gained 0.014 % and
#: cost its test windows 0.13 × the mean predictor, docs/studies/real-sets.md, 2026-12-07).
CLEAR = 2.0


@dataclass(frozen=True)
class CameraMap:
    """This camera's map from a baseline reading's APPD r (%) to APPD: max(0, intercept + slope·r), with the spread
    its posterior sd does not explain (%), learnt from simulated beliefs read on the baseline's own frames."""

    kind: str
    intercept: float
    slope: float
    spread: float
    beliefs: int
    windows: int
    error: float  # leave-one-belief-out mean absolute error of the map (%)
    identity_error: float  # the same of the raw reading (%)

    def apply(self, appd: float, sd: float, threshold_pct: float) -> tuple[float, float, float]:
        """(APPD, sd, p_above) of a reading mapped: sd = sqrt((slope·sd)² + spread²), p_above of a normal."""
        mean = max(0.0, self.intercept + self.slope * appd)
        out_sd = float(np.hypot(self.slope * sd, self.spread))
        z = (threshold_pct - mean) / max(out_sd, 1e-9)
        return float(mean), out_sd, float(0.5 * math.erfc(z / math.sqrt(2.0)))

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in ("kind", "intercept", "slope", "spread", "beliefs", "windows", "error",
                                              "identity_error")}

    @classmethod
    def from_dict(cls, doc: dict) -> CameraMap:
        if doc["kind"] not in KINDS:
            raise ValueError(f"unknown camera map {doc['kind']!r}")
        return cls(str(doc["kind"]), float(doc["intercept"]), float(doc["slope"]), float(doc["spread"]),
                   int(doc["beliefs"]), int(doc["windows"]), float(doc["error"]), float(doc["identity_error"]))


def _fit(kind: str, read: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(intercept, slope) of one kind of map, least squares (slope ≥ 0)."""
    if kind == "identity" or read.size < 2:
        return 0.0, 1.0
    if kind == "shift":
        return float(np.mean(truth - read)), 1.0
    x = np.column_stack([np.ones_like(read), read])
    a, b = np.linalg.lstsq(x, truth, rcond=None)[0]
    if b < 0:
        return float(truth.mean()), 0.0
    return float(a), float(b)


def fit_map(read: np.ndarray, sd: np.ndarray, truth: np.ndarray, group: np.ndarray) -> CameraMap:
    """The simplest map (of KINDS) that no later one clearly beats in leave-one-belief-out absolute error, refitted
    on every window, and the spread of its held-out residuals that the readings' own sds do not explain."""
    read, sd, truth, group = (np.asarray(a, float) for a in (read, sd, truth, group))
    held = {}
    for kind in KINDS:
        pred = np.empty_like(read)
        for g in np.unique(group):
            out = group == g
            a, b = _fit(kind, read[~out], truth[~out])
            pred[out] = np.maximum(0.0, a + b * read[out])
        held[kind] = pred
    absolute = {k: np.abs(p - truth) for k, p in held.items()}
    errors = {k: float(e.mean()) for k, e in absolute.items()}
    kind = KINDS[0]
    for other in KINDS[1:]:
        if clearly_better(absolute[other], absolute[kind], group):
            kind = other
    a, b = _fit(kind, read, truth)
    resid = held[kind] - truth
    spread = float(np.sqrt(max(0.0, np.mean(resid ** 2) - np.mean((b * sd) ** 2))))
    return CameraMap(kind, a, b, spread, int(np.unique(group).size), int(read.size), errors[kind],
                     errors["identity"])


def clearly_better(errors: np.ndarray, than: np.ndarray, group: np.ndarray) -> bool:
    """Whether held-out absolute errors (%) beat `than` by more than CLEAR standard errors of their per-belief
    (group) mean difference."""
    gain = np.array([np.mean(than[group == g] - errors[group == g]) for g in np.unique(group)])
    if gain.size < 2:
        return False
    return bool(gain.mean() > CLEAR * gain.std(ddof=1) / np.sqrt(gain.size))


def learn_map(reference_detector, evidence: Sequence, baseline_of, detector_for, count: int = SIMULATED,
              progress: Callable[[int, int], None] | None = None) -> CameraMap | None:
    """Read `count` simulated beliefs around REF (and REF itself) on the good frames, each part of FOLDS against the
    baseline of the other parts (baseline_of(first, last) → the Baseline of the frames outside [first, last), None
    when they are too weak; detector_for(calib) → a Detector of that belief),
    and fit the camera's map; None when the frames are too few to part."""
    ref, max_fov = reference_detector.belief, reference_detector.max_fov
    evidence = list(evidence)
    if len(evidence) < 2 * FOLDS:
        return None
    edges = np.linspace(0, len(evidence), FOLDS + 1).round().astype(int)
    parts = [(edges[f], edges[f + 1]) for f in range(FOLDS)]
    folds = [baseline_of(a, b) for a, b in parts]
    sampler = Sampler(ref, max_fov=max_fov)
    ref_crop = belief_crop(ref, max_fov)
    rows: list[tuple[float, float, float, int]] = []

    def read_all(det, sim, truth_pct, group):
        for (a, b), bl in zip(parts, folds, strict=True):
            if bl is None:
                continue
            r = det.read(sim[a:b], bl, camera_map=False)
            if r.appd_pct is not None:
                rows.append((r.appd_pct, r.appd_sd_pct, truth_pct, group))

    read_all(reference_detector, evidence, 0.0, 0)
    done, i = 0, 0
    while done < count and i < 20 * count:
        i += 1
        try:
            d = sampler.draw(MAP_SEED, i - 1)
            if d.is_reference:
                continue
            truth_pct = float(appd(ref, d.calib, max_fov=max_fov)[1])
            det = detector_for(d.calib)
        except (UnreachableError, AppdgenError):
            continue
        sim = warp_evidence(evidence, ref, ref_crop, d.calib, belief_crop(d.calib, max_fov))
        done += 1
        read_all(det, sim, truth_pct, done)
        if progress is not None:
            progress(done, count)
    if len({g for *_, g in rows}) < 3:
        return None
    read, sd, truth, group = (np.array(c) for c in zip(*rows, strict=True))
    return fit_map(read, sd, truth, group)
