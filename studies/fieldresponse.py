"""Why a real set's solved field does not follow a belief's field (docs/studies/real-sets.md, "Why the solved field
does not follow a belief"): the rectification, the segments, the solve, and the camera map's simulated beliefs.

    python -m studies.fieldresponse warp [--set euroc] [--belief 14]     # the belief's image against REF's, warped
    python -m studies.fieldresponse project [--set euroc] [--belief 14]  # the evidence along the expected field
    python -m studies.fieldresponse map [--set euroc] [--simulated 12] [--readings runs/realsets/readings.json]

The beliefs are studies.realsets' (index 0 the true file). `warp` rectifies one test frame under REF and under the
belief and compares the belief's image with REF's warped by geometry.bend.output_warp (grey levels; and the residual
shift in tiles, px). `project` reads the first three test windows under the belief, from its own rectification
(real) and from REF's edge points warped into it (appdgen.detect.simulate, as the camera map does), and prints the
expected field's size (rms px per grid node), the evidence's response along the expected field's direction alone
(score over information: the coefficient it asks for along that direction) and the pooled solve's, the solved
field's slope on the expected one (less what the frames read under the true file), the solve's coefficient on the
segments both evidences found (matched: centres within 4 px, normals and spans alike) and on random subsets of the
real segments as large, and how the two evidences' long segments differ in curvature. `map` learns the
camera's map from simulated beliefs warped (the product) and really rectified (the frames rectified under each
simulated belief and searched again, as `appdgen build` would make them), prints how their readings follow their
truth, and, given a studies.realsets readings file, the map applied to that set's windows read with the baseline
(their readings before the product's map).
"""
from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

import appdgen
import appdgen.detect.simulate as simulate
from appdgen.detect import Detector
from appdgen.detect.edges import EdgePoints, collect_points, segment_coefficients
from appdgen.detect.model import belief_crop
from appdgen.detect.solve import detrend, pool, segment_noise, solve
from appdgen.detect.tracks import track_ids
from appdgen.geometry.bend import output_rest, output_warp
from appdgen.geometry.crop import valid_region
from studies.realsets import SETS, RealSet, beliefs, raw_frames, scores

TILE = 96  # px, the phase-correlation tiles of `warp`
LONG = 120.0  # px: segments this long or longer have their curvatures compared between the two evidences
RANDOM_SUBSETS = 6  # random subsets of the real segments, as many as are found in both, solved in `project`


def warp(s: RealSet, k: int) -> None:
    """Mean |I_b − I_ref∘W| against |I_b − I_ref| (grey levels) and the largest residual tile shift (px)."""
    truth = appdgen.load(str(s.calib))
    belief, pct = beliefs(truth, k)[k]
    raw = raw_frames(s, s.test[0] + 5, 1)[0]
    i0 = Detector(truth).rectify(raw).astype(np.float32)
    ib = Detector(belief).rectify(raw).astype(np.float32)
    h, w = i0.shape
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
    qu, qv = output_warp(truth, belief_crop(truth, None), belief, belief_crop(belief, None), uu.ravel(), vv.ravel())
    qu, qv = qu.reshape(h, w).astype(np.float32), qv.reshape(h, w).astype(np.float32)
    pred = cv2.remap(i0, qu, qv, cv2.INTER_CUBIC)
    inside = (qu > 5) & (qu < w - 6) & (qv > 5) & (qv < h - 6)
    inside[:20], inside[-20:], inside[:, :20], inside[:, -20:] = False, False, False, False
    window = cv2.createHanningWindow((TILE, TILE), cv2.CV_32F)
    shifts = [cv2.phaseCorrelate(pred[y:y + TILE, x:x + TILE], ib[y:y + TILE, x:x + TILE], window)[0]
              for y in range(40, h - TILE - 40, 120) for x in range(40, w - TILE - 40, 130)]
    print(f"belief {k} (APPD {pct:.2f} %): mean |I_b - I_ref(W)| {np.abs(ib - pred)[inside].mean():.2f}, "
          f"|I_b - I_ref| {np.abs(ib - i0)[inside].mean():.2f} grey levels; largest tile shift "
          f"{np.abs(np.array(shifts)).max():.2f} px over {len(shifts)} tiles")


def direction_response(det: Detector, evidence: list, expected: np.ndarray) -> tuple[float, float]:
    """(score / information along the expected field's coefficients' direction alone, the pooled solve's
    coefficient along it)."""
    used = [e.points for e in evidence if e.segments]
    d = pool([det.design(p) for p in used], track_ids(used))
    est = solve(d, det.model.var, det.solve_params)  # what det.estimate solves, on the design already pooled
    t = detrend(np.column_stack([d.y, d.x]), d, np.ones(d.y.size))
    yt, xt = t[:, 0], t[:, 1:]
    pw = 1.0 / segment_noise(yt - xt @ est.c, d, np.ones(d.y.size), det.solve_params)[d.seg]
    unit = expected / np.linalg.norm(expected)
    along = xt @ unit
    return float((pw * yt * along).sum() / (pw * along ** 2).sum()), float(est.c @ unit)


def matches(pa: EdgePoints, pb: EdgePoints, least: float = 0.0) -> list[tuple[int, int]]:
    """(i, j): segment i of pa that is segment j of pb (j at least `least` px long): centres within 4 px, normals
    within 2.6°, spans within 20 %."""
    out = []
    if not pa.segments:
        return out
    for j in np.flatnonzero(pb.length >= least):
        near = np.hypot(*(pa.centre - pb.centre[j]).T)
        ok = (near < 4) & (np.abs(pa.normal @ pb.normal[j]) > 0.999) & (np.abs(pa.length - pb.length[j]) <
                                                                         0.2 * pb.length[j])
        if ok.any():
            out.append((int(np.flatnonzero(ok)[np.argmin(near[ok])]), int(j)))
    return out


def only(evidence, keep: np.ndarray):
    """A frame's Evidence with only the segments where keep (S,) is true."""
    p = evidence.points
    n = p.normal[p.seg]
    pts = collect_points(p.u - p.e * n[:, 0], p.v - p.e * n[:, 1], p.s, p.e, p.seg, p.normal, p.contrast,
                         keep[p.seg], 1)
    return replace(evidence, segments=pts.segments, points=pts)


def curvature_gap(real: list, warped: list) -> tuple[float, float, int]:
    """(correlation, rms difference) of matched long segments' curvatures (px per (100 px)²), and their number
    (NaNs below two matched)."""
    pairs = []
    for a, b in zip(real, warped, strict=True):
        pa, pb = a.points, b.points
        if not pa.segments or not pb.segments:
            continue
        ka = segment_coefficients(pa.s / 100, pa.e, pa.seg, np.ones(pa.s.size), pa.segments, 2)[:, 2]
        kb = segment_coefficients(pb.s / 100, pb.e, pb.seg, np.ones(pb.s.size), pb.segments, 2)[:, 2]
        pairs += [(np.sign(pa.normal[i] @ pb.normal[j]) * ka[i], kb[j]) for i, j in matches(pa, pb, LONG)]
    if len(pairs) < 2:
        return float("nan"), float("nan"), len(pairs)
    x = np.array(pairs)
    return float(np.corrcoef(x[:, 0], x[:, 1])[0, 1]), float(np.sqrt(((x[:, 0] - x[:, 1]) ** 2).mean())), len(x)


def project(s: RealSet, k: int) -> None:
    """The first three windows under belief k: the expected field, the evidence along it and the solve's."""
    truth = appdgen.load(str(s.calib))
    belief, pct = beliefs(truth, k)[k]
    ref, det = Detector(truth), Detector(belief)
    crops = (belief_crop(truth, None), belief_crop(belief, None))
    m = det.model
    uu, vv = np.meshgrid(m.grid_u, m.grid_v)
    expected = output_rest(truth, valid_region(truth), belief, crops[1], uu, vv).reshape(uu.shape + (2,))
    coefs = (expected - m.mean).reshape(-1) @ m.basis.reshape(len(m.basis), -1).T
    rms = float(np.sqrt((expected ** 2).sum(-1).mean()))
    for first in range(s.test[0], s.test[0] + 3 * s.window, s.window):
        raws = raw_frames(s, first, s.window)
        under_ref = [ref.evidence(r) for r in raws]
        scenery = ref.model.field_of(ref.estimate(under_ref).c)  # what these frames read under the true file
        real = [det.evidence(r) for r in raws]
        warped = simulate.warp_evidence(under_ref, truth, crops[0], belief, crops[1])
        cells = []
        for name, ev in (("real", real), ("warped", warped)):
            alone, solved = direction_response(det, ev, coefs)
            field = m.field_of(det.estimate(ev).c) - scenery
            cells.append(f"{name}: alone {alone:.0f}, solve {solved:.1f}, slope "
                         f"{(field * expected).sum() / (expected ** 2).sum():+.2f}")
        kept = []  # per frame: (real, warped) masks of the segments found in both
        for a, b in zip(real, warped, strict=True):
            pairs = np.array(matches(a.points, b.points), int).reshape(-1, 2)
            kept.append(tuple(np.isin(np.arange(e.points.segments), pairs[:, side])
                              for side, e in ((0, a), (1, b))))
        both = [direction_response(det, [only(e, masks[side]) for e, masks in zip(ev, kept, strict=True)], coefs)[1]
                for side, ev in ((0, real), (1, warped))]
        rng = np.random.default_rng(0)
        found = int(sum(masks[0].sum() for masks in kept))
        share = found / max(sum(e.segments for e in real), 1)
        halves = [direction_response(det, [only(e, rng.random(e.points.segments) < share) for e in real], coefs)[1]
                  for _ in range(RANDOM_SUBSETS)]
        cells.append(f"the {found} segments found in both: solve real {both[0]:.1f}, "
                     f"warped {both[1]:.1f}; random subsets of the real ones as large: {min(halves):.1f} to "
                     f"{max(halves):.1f}")
        corr, gap, n = curvature_gap(real, warped)
        print(f"belief {k} (APPD {pct:.2f} %, field {rms:.2f} px, coefficient {np.linalg.norm(coefs):.0f}) "
              f"frames {first}-{first + s.window - 1}: " + "; ".join(cells)
              + f"; {n} long segments: curvature corr {corr:.2f}, rms difference {gap:.2f}")


def unmapped(row: dict) -> tuple[float, float]:
    """A studies.realsets window's reading before the product's camera map (APPD, sd; %)."""
    if row.get("raw") is not None:
        return row["raw"], row["raw_sd"]
    return row["appd"], row["sd"]


def camera_map(s: RealSet, simulated: int, readings: Path | None, name: str) -> None:
    """The camera's map from warped and from really rectified simulated beliefs, and on the set's windows."""
    truth = appdgen.load(str(s.calib))
    raws = raw_frames(s, s.baseline[0], s.baseline[1] - s.baseline[0])
    ref = Detector(truth)
    evidence = [ref.evidence(r) for r in raws]
    product_warp, product_fit = simulate.warp_evidence, simulate.fit_map

    def rectified(_evidence, _reference, _reference_crop, belief, _belief_crop):
        det = Detector(belief)
        return [det.evidence(r) for r in raws]

    def fit_and_show(read, sd, truth_pct, group):
        line = np.polyfit(truth_pct, read, 1)
        print(f"  simulated reads on truth: slope {line[0]:.2f}, intercept {line[1]:.2f}, "
              f"correlation {np.corrcoef(truth_pct, read)[0, 1]:.2f}")
        return product_fit(read, sd, truth_pct, group)

    found = json.loads(readings.read_text()) if readings is not None and readings.exists() else []
    windows = [r for x in found if x["set"] == name for r in x["rows"] if r["baseline"] and r["appd"] is not None]
    mean = next((x["mean"] for x in found if x["set"] == name), None)
    try:
        simulate.fit_map = fit_and_show
        for how, sim in (("warped", product_warp), ("rectified", rectified)):
            simulate.warp_evidence = sim
            print(f"{name}, {simulated} simulated beliefs {how}:")
            cm = ref.save_baseline(evidence, "baseline", simulated=simulated).camera_map
            print(f"  map {cm.kind}: intercept {cm.intercept:.2f}, slope {cm.slope:.2f}, spread {cm.spread:.3f}, "
                  f"held-out error {cm.error:.3f} (identity {cm.identity_error:.3f})")
            if windows:
                mapped = [dict(r) | dict(zip(("appd", "sd", "p"), cm.apply(*unmapped(r), 0.5), strict=True))
                          for r in windows]
                for r in mapped:
                    r["verdict"] = "miscalibrated" if r["p"] >= 0.95 else "uncertain"
                sc = scores({"set": name, "mean": mean, "rows": mapped}, with_baseline=True)
                print(f"  on the windows: MAE / mean {sc['mae_vs_mean']:.2f}, coverage {sc['coverage']:.2f}, true "
                      f"flagged {sc['true_flagged']}, above 0.5 % flagged {sc['above_flagged']}")
    finally:
        simulate.warp_evidence, simulate.fit_map = product_warp, product_fit


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("study", choices=("warp", "project", "map"))
    ap.add_argument("--set", default="euroc", choices=sorted(SETS))
    ap.add_argument("--belief", type=int, default=14)
    ap.add_argument("--simulated", type=int, default=simulate.SIMULATED)
    ap.add_argument("--readings", type=Path, default=None)
    a = ap.parse_args(argv)
    s = SETS[a.set]
    if a.study == "warp":
        warp(s, a.belief)
    elif a.study == "project":
        project(s, a.belief)
    else:
        camera_map(s, a.simulated, a.readings, a.set)


if __name__ == "__main__":
    main()
