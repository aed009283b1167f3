"""What bends edges that are straight: the sub-pixel edge localiser's own bias, and the scene edges' own bend, on
real frames under their true files and on synthetic streets (docs/studies/real-sets.md, "What bends a straight
edge").

    python -m studies.edgebias locking      # a tilted straight step: the edge offset's error by sub-pixel phase
    python -m studies.edgebias bend         # scene edges' own bend beyond noise, by length: desk, EuRoC, streets
    python -m studies.edgebias weight       # which segments carry the field's first coefficient, ideal streets

`locking` draws an exact (32× supersampled) straight step at three slopes and blurs, finds its edge points with
appdgen.detect.edges and prints their error from the true line binned by the true edge's sub-pixel phase (px),
then the wave's amplitude for other smoothings (EdgeParams.sigma) and for an 8× supersampled step.
`bend` fits each segment's quadratic in s/100 px and prints τ, the spread of the curvature beyond each segment's
own noise (method of moments on medians, px per (100 px)²), by segment length, under the true calibration.
`weight` solves ideal pinhole street frames (no lens: every edge straight but for the scene's own) with the
product's third-order lookup and prints each frame's first coefficient (prior sd in the line) and the share
of its score carried by the five segments that carry most, with those segments' span and place.
"""
from __future__ import annotations

import argparse

import cv2
import numpy as np

import appdgen
from appdgen.calib.defaults import default_calibration
from appdgen.detect import Detector
from appdgen.detect.edges import EdgeParams, EdgePoints, edge_points, segment_fit
from appdgen.sources.decode import as_channels
from appdgen.synth import frame_rng, render_frame, render_ideal, scale_calibration
from studies.realsets import SETS, SHARED, RealSet, raw_frames

LENGTHS = ((40, 80), (80, 160), (160, 10_000))  # px, segment span classes
PHASES = 8  # bins of the true edge's sub-pixel phase


def step_image(slope: float, offset: float, blur: float, size=(800, 200), supersample: int = 8) -> np.ndarray:
    """Grey uint8 image, bright above the line y = offset + slope·x (px), area-sampled, blurred by blur px."""
    w, h = size
    ys = (np.arange(h * supersample) + 0.5) / supersample
    xs = (np.arange(w * supersample) + 0.5) / supersample
    fine = (ys[:, None] < offset + slope * xs[None, :]).astype(np.float32)
    img = fine.reshape(h, supersample, w, supersample).mean((1, 3))
    if blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur)
    return np.clip(np.rint(60 + 120 * img), 0, 255).astype(np.uint8)


def phase_error(slope: float, blur: float, prm: EdgeParams | None = None, supersample: int = 32,
                offset: float = 80.3) -> tuple[np.ndarray, int]:
    """The edge points' mean error from the true line (px, mean removed) in PHASES bins of the true edge's sub-pixel
    phase, and how many points the longest segment has."""
    p = edge_points(step_image(slope, offset, blur, supersample=supersample), prm or EdgeParams())
    m = p.seg == int(np.argmax(p.length))
    truth = offset + slope * p.u[m]
    err = (p.v[m] - truth) / np.hypot(1.0, slope)
    err -= err.mean()
    phase = np.minimum((truth % 1.0 * PHASES).astype(int), PHASES - 1)
    return np.array([err[phase == i].mean() for i in range(PHASES)]), int(m.sum())


def locking() -> None:
    """The edge offset's error by the true edge's sub-pixel phase, for a straight step at three slopes."""
    for blur in (0.0, 0.5, 1.0):
        for slope in (0.004, 0.013, 0.05):
            by, points = phase_error(slope, blur)
            print(f"blur {blur} slope {slope}: {points} points; error by phase " + " ".join(f"{x:+.3f}" for x in by))
    for sigma in (0.7, 1.0, 1.5, 2.0):
        amps = [np.ptp(phase_error(slope, 0.5, EdgeParams(sigma=sigma))[0]) / 2 for slope in (0.004, 0.05)]
        print(f"smoothing sigma {sigma}: amplitude {amps[0]:.3f} / {amps[1]:.3f} px (slope 0.004 / 0.05)")
    amps = [np.ptp(phase_error(slope, 0.5, supersample=8)[0]) / 2 for slope in (0.004, 0.05)]
    print(f"an 8x supersampled step: amplitude {amps[0]:.3f} / {amps[1]:.3f} px")


def curvatures(frames: list[EdgePoints]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each segment's curvature (px per (100 px)²), its noise variance and its span (px)."""
    ks, vs, spans = [], [], []
    for p in frames:
        if p.segments == 0:
            continue
        n, w = p.segments, np.ones(p.s.size)
        q = (p.s / 100.0) ** 2
        r = p.e - segment_fit(p.s, p.e, p.seg, w, n, 1)
        qd = q - segment_fit(p.s, q, p.seg, w, n, 1)
        qq = np.bincount(p.seg, qd * qd, n)
        k = np.bincount(p.seg, qd * r, n) / qq
        noise = np.bincount(p.seg, (r - k[p.seg] * qd) ** 2, n) / np.maximum(np.bincount(p.seg, None, n) - 3, 1)
        ks.append(k)
        vs.append(noise / qq)
        spans.append(p.length)
    return np.concatenate(ks), np.concatenate(vs), np.concatenate(spans)


def spread(k: np.ndarray, v: np.ndarray) -> float:
    """τ: the curvature's sd beyond noise, so that the median of k²/(τ² + v) is χ²₁'s (0.455)."""
    lo, hi = 1e-10, max(float((k ** 2).max()), 1e-9)
    if np.median(k ** 2 / (lo + v)) <= 0.455:
        return 0.0
    for _ in range(60):
        mid = np.sqrt(lo * hi)
        lo, hi = (mid, hi) if np.median(k ** 2 / (mid + v)) > 0.455 else (lo, mid)
    return float(np.sqrt(hi))


def real_frames(s: RealSet, frames: int) -> list[EdgePoints]:
    """Edge points of the first `frames` test frames of a real set (studies.realsets), rectified under its true
    file."""
    det = Detector(appdgen.load(str(s.calib)))
    return [det.evidence(raw).points for raw in raw_frames(s, s.test[0], frames)]


def bend() -> None:
    """τ by segment length on the desk, EuRoC (true files) and synthetic streets (rendered and ideal)."""
    sets = {}
    if SHARED.exists():
        sets["desk 101-160"] = real_frames(SETS["desk"], 60)
        sets["EuRoC 35-94"] = real_frames(SETS["euroc"], 60)
    cam = scale_calibration(default_calibration("02"), 0.5)
    det = Detector(cam, library_draws=200)
    sets["streets (30)"] = [det.evidence(render_frame(cam, frame_rng(11, i))).points for i in range(30)]
    sets["ideal streets (30)"] = [edge_points(as_channels(render_ideal(cam, frame_rng(11, i)), 1)) for i in range(30)]
    for name, frames in sets.items():
        k, v, span = curvatures(frames)
        cells = []
        for lo, hi in LENGTHS:
            m = (span >= lo) & (span < hi)
            cells.append(f"{lo}-{hi if hi < 10_000 else ''} px: {m.sum()} segments, τ {spread(k[m], v[m]):.3f}, "
                         f"noise {np.median(np.sqrt(v[m])):.3f}")
        print(f"{name}: " + "; ".join(cells))


def weight(frames: int = 5) -> None:
    """Per ideal street frame: c₀ solved, and the five segments carrying most of its score."""
    from appdgen.detect.solve import detrend, solve

    cam = scale_calibration(default_calibration("02"), 0.5)
    det = Detector(cam, library_draws=200)
    print(f"prior sd of c0: {np.sqrt(det.model.var[0]):.0f}")
    for i in range(frames):
        p = edge_points(as_channels(render_ideal(cam, frame_rng(11, i)), 1))
        d = det.design(p)
        c0 = solve(d, det.model.var).c[0]
        t = detrend(np.column_stack([d.y, d.x[:, 0]]), d, np.ones(d.y.size))
        score = np.bincount(d.seg, t[:, 0] * t[:, 1], d.nseg)
        top = np.argsort(-np.abs(score))[:5]
        where = ", ".join(f"{p.length[j]:.0f} px at x {p.centre[j, 0]:.0f}" for j in top)
        print(f"frame {i}: c0 {c0:+.0f}, {d.nseg} segments, the top five carry {score[top].sum() / score.sum():.2f}"
              f" of its score: {where}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("study", choices=("locking", "bend", "weight"))
    {"locking": locking, "bend": bend, "weight": weight}[ap.parse_args(argv).study]()


if __name__ == "__main__":
    main()
