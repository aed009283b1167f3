"""Line evidence of one rectified grey image: LSD segments joined along collinear pieces, and edge points along
each refined to sub-pixel along the segment's normal (all in output pixels of the image).

A point of segment j sits at (x0 + s·tx, y0 + s·ty) + e·n on the line through (x0, y0) along (tx, ty), with normal
n = (−ty, tx): s its arc position (px), e its sub-pixel offset (px), found as the peak of the smoothed gradient
profile along n (a Gaussian through the three samples around the maximum).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class EdgeParams:
    """How segments are found, joined and sampled (lengths in output px)."""

    lsd_scale: float = 0.4  # LSD finds segments on the image scaled by this (5× faster than its 0.8 at KITTI's
    #                         size, as many segments over 40 px); the edge points are then refined at full size
    min_len: float = 40.0  # a (joined) segment spans at least this
    piece_len: float = 15.0  # shortest LSD piece considered
    merge_angle: float = 2.0  # degrees between pieces joined
    merge_dist: float = 2.0  # a piece's ends from the growing line
    merge_gap: float = 80.0  # largest gap bridged (no points are taken in it)
    step: float = 3.0  # between points
    end_margin: float = 3.0  # left out at each piece's ends
    #: Gaussian smoothing before the gradient: less smoothing lets a neighbouring edge pull the peak less (unseen
    #: streets 0.75 / 0.51 x the mean predictor at 1.0, 0.70 / 0.44 at 0.7; docs/studies/real-sets.md, 2026-12-07)
    sigma: float = 0.7
    half: int = 3  # the profile spans −half..half px along the normal
    min_points: int = 10
    outlier_px: float = 1.0  # points further from their segment's robust curve are dropped (or 3 MAD if larger)
    weak: float = 0.4  # points whose gradient peak is under this fraction of their segment's median are dropped


@dataclass(frozen=True)
class EdgePoints:
    """Sub-pixel edge points of one image, grouped by segment (arrays of N points; S segments)."""

    u: np.ndarray  # edge point, output px
    v: np.ndarray
    s: np.ndarray  # arc position along its segment's line, centred per segment, px
    e: np.ndarray  # offset from the segment's line along its normal, px
    seg: np.ndarray  # segment index 0..S−1
    normal: np.ndarray  # (S, 2) unit normal of each segment's line
    centre: np.ndarray  # (S, 2) mid-point of each segment's points, output px
    length: np.ndarray  # (S,) span of each segment's points, px
    contrast: np.ndarray  # (S,) median gradient peak (grey levels per px, signed by polarity)

    @property
    def segments(self) -> int:
        """Number of segments."""
        return len(self.length)


def empty_points() -> EdgePoints:
    """No evidence."""
    z = np.zeros(0)
    return EdgePoints(z, z, z, z, np.zeros(0, int), np.zeros((0, 2)), np.zeros((0, 2)), z, z)


def segment_coefficients(s: np.ndarray, z: np.ndarray, seg: np.ndarray, w: np.ndarray, nseg: int, degree: int
                         ) -> np.ndarray:
    """Per-segment weighted least-squares polynomial in s (px) of z (N,) or each column of z (N, M): its
    coefficients, lowest power first (S × (d+1), or S × (d+1) × M; units of z per px^k)."""
    powers = np.stack([s ** k for k in range(degree + 1)], axis=1)  # N × (d+1)
    gram = np.zeros((nseg, degree + 1, degree + 1))
    for a in range(degree + 1):
        for b in range(a, degree + 1):
            gram[:, a, b] = gram[:, b, a] = np.bincount(seg, w * powers[:, a] * powers[:, b], nseg)
    scale = np.trace(gram, axis1=1, axis2=2)[:, None, None] + 1e-12
    gram = gram + 1e-9 * scale * np.eye(degree + 1)  # degenerate segments (one point) stay solvable
    zz = z[:, None] if z.ndim == 1 else z
    rhs = np.stack([np.stack([np.bincount(seg, w * powers[:, a] * zz[:, j], nseg) for a in range(degree + 1)], 1)
                    for j in range(zz.shape[1])], axis=2)  # S × (d+1) × M
    coef = np.linalg.solve(gram, rhs)
    return coef[..., 0] if z.ndim == 1 else coef


def segment_fit(s: np.ndarray, z: np.ndarray, seg: np.ndarray, w: np.ndarray, nseg: int, degree: int
                ) -> np.ndarray:
    """Per-segment weighted least-squares polynomial in s of z (N,) or each column of z (N, M): fitted values."""
    powers = np.stack([s ** k for k in range(degree + 1)], axis=1)  # N × (d+1)
    coef = segment_coefficients(s, z, seg, w, nseg, degree)
    fitted = np.einsum("nd,ndm->nm", powers, (coef[..., None] if z.ndim == 1 else coef)[seg])
    return fitted[:, 0] if z.ndim == 1 else fitted


def grouped_median(x: np.ndarray, seg: np.ndarray, nseg: int) -> np.ndarray:
    """(S,) median of x within each segment (0 where a segment has no point)."""
    order = np.lexsort((x, seg))
    counts = np.bincount(seg, minlength=nseg)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    lo = starts + np.maximum(counts - 1, 0) // 2
    hi = starts + counts // 2
    xs = x[order]
    out = np.zeros(nseg)
    has = counts > 0
    out[has] = 0.5 * (xs[np.minimum(lo[has], len(xs) - 1)] + xs[np.minimum(hi[has], len(xs) - 1)])
    return out


def detect_lines(img: np.ndarray, scale: float = 0.8) -> np.ndarray:
    """LSD segments (x0, y0, x1, y1; px of img) of a grey uint8 image, found at `scale`; their direction carries
    the edge's polarity."""
    lines = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD, scale).detect(img)[0]
    return np.zeros((0, 4)) if lines is None else lines.reshape(-1, 4).astype(np.float64)


def join_lines(lines: np.ndarray, prm: EdgeParams) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Collinear pieces of the same polarity joined, longest first: (point, direction, arc positions to sample)."""
    length = np.hypot(lines[:, 2] - lines[:, 0], lines[:, 3] - lines[:, 1])
    keep = length >= prm.piece_len
    lines, length = lines[keep], length[keep]
    order = np.argsort(-length)
    lines, length = lines[order], length[order]
    t = (lines[:, 2:4] - lines[:, 0:2]) / np.maximum(length, 1e-9)[:, None]
    free = np.ones(len(lines), bool)
    cos_tol = np.cos(np.radians(prm.merge_angle))
    out = []
    for i in range(len(lines)):
        if not free[i]:
            continue
        free[i] = False
        members = np.array([i])
        p0, ti = lines[i, 0:2], t[i]
        for _ in range(3):  # grow, refit, grow again: a joined line's direction is better than one piece's
            n = np.array([-ti[1], ti[0]])
            cand = np.flatnonzero(free & (t @ ti >= cos_tol))
            if cand.size == 0:
                break
            a, b = lines[cand, 0:2] - p0, lines[cand, 2:4] - p0
            ends = np.concatenate([lines[members, 0:2], lines[members, 2:4]]) - p0
            lo, hi = (ends @ ti).min(), (ends @ ti).max()
            sa, sb = a @ ti, b @ ti
            gap = np.maximum(np.minimum(sa, sb) - hi, lo - np.maximum(sa, sb))
            ok = (np.abs(a @ n) <= prm.merge_dist) & (np.abs(b @ n) <= prm.merge_dist) & (gap <= prm.merge_gap)
            if not ok.any():
                break
            free[cand[ok]] = False
            members = np.concatenate([members, cand[ok]])
            pts = np.concatenate([lines[members, 0:2], lines[members, 2:4]])
            wts = np.concatenate([length[members], length[members]])
            p0 = (pts * wts[:, None]).sum(0) / wts.sum()
            evals, evecs = np.linalg.eigh(((pts - p0) * wts[:, None]).T @ (pts - p0))
            ti = evecs[:, 1] * (1.0 if evecs[:, 1] @ ti >= 0 else -1.0)
        s0 = (lines[members, 0:2] - p0) @ ti
        s1 = (lines[members, 2:4] - p0) @ ti
        lo, hi = np.minimum(s0, s1), np.maximum(s0, s1)
        if hi.max() - lo.min() < prm.min_len:
            continue
        s = np.concatenate([np.arange(a + prm.end_margin, b - prm.end_margin + 1e-9, prm.step) for a, b in
                        zip(lo, hi, strict=True)])
        out.append((p0, ti, np.unique(np.round(s / prm.step) * prm.step)))
    return out


def gradient_images(img: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """x and y derivatives (grey levels per px) of the image smoothed by a Gaussian of sigma px."""
    g = cv2.GaussianBlur(img.astype(np.float32), (0, 0), sigma)
    return (cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3, scale=0.125), cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3, scale=0.125))


def edge_points(img: np.ndarray, prm: EdgeParams = EdgeParams()) -> EdgePoints:
    """Sub-pixel edge points of the joined segments of a grey uint8 image (output px)."""
    joined = join_lines(detect_lines(img, prm.lsd_scale), prm)
    if not joined:
        return empty_points()
    h, w = img.shape
    gx, gy = gradient_images(img, prm.sigma)
    seg = np.concatenate([np.full(s.size, i) for i, (_, _, s) in enumerate(joined)])
    s = np.concatenate([s for _, _, s in joined])
    p0 = np.array([p for p, _, _ in joined])[seg]
    t = np.array([d for _, d, _ in joined])
    n = np.column_stack([-t[:, 1], t[:, 0]])
    bu, bv = p0[:, 0] + t[seg, 0] * s, p0[:, 1] + t[seg, 1] * s
    offs = np.arange(-prm.half, prm.half + 1, dtype=np.float64)
    mx = (bu[:, None] + offs * n[seg, 0:1]).astype(np.float32)
    my = (bv[:, None] + offs * n[seg, 1:2]).astype(np.float32)
    inside = ((mx >= 2) & (mx <= w - 3) & (my >= 2) & (my <= h - 3)).all(1)
    prof = (cv2.remap(gx, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT_101) * n[seg, 0:1]
            + cv2.remap(gy, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT_101) * n[seg, 1:2])
    nseg = len(joined)
    polarity = np.where(np.bincount(seg, prof[:, prm.half], nseg) >= 0, 1.0, -1.0)
    prof = prof * polarity[seg][:, None]
    j = np.clip(np.argmax(prof, axis=1), 1, 2 * prm.half - 1)
    rows = np.arange(len(j))
    a, b, c = prof[rows, j - 1], prof[rows, j], prof[rows, j + 1]
    ok = inside & (a > 0) & (b > 0) & (c > 0) & (b >= a) & (b >= c)
    la, lb, lc = (np.log(np.maximum(x, 1e-6)) for x in (a, b, c))
    den = np.where(la - 2 * lb + lc < -1e-9, la - 2 * lb + lc, -1.0)
    delta = 0.5 * (la - lc) / den
    ok &= np.abs(delta) <= 0.6
    e = offs[j] + delta
    peak = grouped_median(np.where(ok, b, 0.0), seg, nseg)  # (zeros pull it down: a lenient threshold)
    ok &= b >= prm.weak * peak[seg]
    keep = _robust_points(s, e, seg, ok, nseg, prm)
    return collect_points(bu, bv, s, e, seg, n, polarity * peak, keep, prm.min_points)


def _robust_points(s: np.ndarray, e: np.ndarray, seg: np.ndarray, ok: np.ndarray, nseg: int, prm: EdgeParams
                   ) -> np.ndarray:
    """Points kept: close to their segment's robust quadratic (a bent long line is the signal, not an outlier)."""
    keep = ok.copy()
    for _ in range(2):
        fit = segment_fit(s, e, seg, keep.astype(float), nseg, 2)
        res = np.abs(e - fit)
        mad = grouped_median(np.where(keep, res, 0.0), seg, nseg)
        keep = ok & (res <= np.maximum(prm.outlier_px, 3 * 1.4826 * mad)[seg])
    return keep


def collect_points(bu, bv, s, e, seg, n, contrast, keep, min_points: int) -> EdgePoints:
    """EdgePoints (at bu, bv + e·n) of the kept points of segments with at least min_points, renumbered."""
    counts = np.bincount(seg, keep.astype(int), len(n))
    good = counts >= min_points
    keep = keep & good[seg]
    if not keep.any():
        return empty_points()
    new = np.cumsum(good) - 1
    sg = new[seg[keep]]
    nseg = int(good.sum())
    ss, ee = s[keep], e[keep]
    nn = n[good]
    u, v = bu[keep] + ee * nn[sg, 0], bv[keep] + ee * nn[sg, 1]
    cnt = np.bincount(sg, minlength=nseg)
    mid = np.bincount(sg, ss, nseg) / cnt
    lo = np.full(nseg, np.inf)
    hi = np.full(nseg, -np.inf)
    np.minimum.at(lo, sg, ss)
    np.maximum.at(hi, sg, ss)
    centre = np.column_stack([np.bincount(sg, u, nseg), np.bincount(sg, v, nseg)]) / cnt[:, None]
    return EdgePoints(u, v, ss - mid[sg], ee, sg, nn, centre, hi - lo, contrast[good])
