"""The robust solve for the field's coefficients from edge points, pooled over any number of frames in one solve.

Along a segment, points p_i = base_i + e_i·n of a straight scene edge have p_i + f(p_i) collinear, f = μ + Σ c_k B_k
the field (output px): y_i = e_i + n·μ(p_i) = a + b·s_i − Σ c_k n·B_k(p_i) (+ noise). The segment's own line (a, b)
is a nuisance removed by a weighted per-segment detrend of y and of the design X = −n·B; c is solved by iteratively
reweighted least squares (each segment weighted by its own noise, shrunk towards the median; Huber on points;
segments far noisier than the median dropped) with the library's prior on c. Out: the MAP c, its covariance, and the
likelihood's sufficient statistics H = XᵀWX, g = XᵀWy for the posterior over the library.

Scene edges are not all straight (a kerb's curve, a cushion, a curtain's fold), and the likelihood of independent
points lets one long curved edge outvote everything (its curvature information grows as n·L⁴). So each scene edge
also carries a random curvature κ ~ N(0, τ²) of its own, shared by every observation of it (a track: the same edge
in consecutive frames, appdgen.detect.tracks): a curved edge keeps its curvature as it moves, while the field's
bend changes with where the edge is in the image. κ is marginalised in closed form (Woodbury, per track), which caps
what one edge can say about the field at what its curvature's spread τ allows; τ² is estimated from the segments
themselves (method of moments on their own curvatures, above each one's noise), never below TAU_FLOOR.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from appdgen.detect.edges import segment_fit


#: px: arc positions are scaled by this before squaring (curvatures in px per (ARC_UNIT px)²: O(1) numbers).
ARC_UNIT = 100.0


@dataclass(frozen=True)
class Design:
    """Observations of one or more frames: y (N,), X (N, K), arc position s (N,), segment index (N,), nseg, and
    each segment's scene edge (track, (nseg,); None: every segment its own edge)."""

    y: np.ndarray
    x: np.ndarray
    s: np.ndarray
    seg: np.ndarray
    nseg: int
    track: np.ndarray | None = None

    def tracks(self) -> np.ndarray:
        """(nseg,) the scene edge of each segment, numbered 0..T−1."""
        return np.arange(self.nseg) if self.track is None else np.unique(self.track, return_inverse=True)[1]


def pool(designs: list[Design], tracks: list[np.ndarray] | None = None) -> Design:
    """Designs of several frames stacked, segments renumbered (each keeps its own nuisance line); tracks: each
    frame's segments' scene-edge ids, shared across frames (None: every segment its own edge)."""
    offsets = np.cumsum([0] + [d.nseg for d in designs])
    if tracks is None:
        track = None
    else:
        track = np.concatenate(tracks)
    return Design(np.concatenate([d.y for d in designs]), np.vstack([d.x for d in designs]),
                  np.concatenate([d.s for d in designs]),
                  np.concatenate([d.seg + o for d, o in zip(designs, offsets)]), int(offsets[-1]), track)


@dataclass(frozen=True)
class SolveParams:
    """The robust solve's settings (px where a length)."""

    huber: float = 1.0  # points beyond huber × their segment's sigma are down-weighted
    seg_rms: float = 2.5  # segments whose sigma exceeds seg_rms × the median are dropped
    sigma_floor: float = 0.02  # no segment is trusted more than this
    shrink: float = 20.0  # points' worth of the median variance mixed into each segment's own
    iters: int = 6
    tau_floor: float = 0.0  # px per ARC_UNIT²: the least spread of scene edges' curvature (0: no random curvature)
    random_curvature: bool = False  # measured on synthetic streets: it costs more than it gains (report)
    nu: float = 3.0  # degrees of freedom of the scene edges' curvature (Student t: heavy tails)


@dataclass(frozen=True)
class Estimate:
    """The solve's result: MAP c, its covariance, H and g of the likelihood, the noise and what was used."""

    c: np.ndarray
    cov: np.ndarray
    h: np.ndarray
    g: np.ndarray
    sigma: float  # median segment noise, px
    segments: int  # segments used
    points: int  # points used (weight > 0)
    tau: float = 0.0  # spread of the scene edges' curvature, px per ARC_UNIT²
    tracks: int = 0  # scene edges the used segments belong to


def detrend(z: np.ndarray, d: Design, w: np.ndarray, degree: int = 1) -> np.ndarray:
    """z (N,) or (N, K) minus its weighted least-squares polynomial in s per segment."""
    return z - segment_fit(d.s, z, d.seg, w, d.nseg, degree)


def segment_noise(r: np.ndarray, q: np.ndarray, d: Design, ww: np.ndarray, prm: SolveParams
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each segment's noise variance (residual r less its own curvature along q, shrunk to the median), its
    curvature estimate (q·r/q·q) and that estimate's noise variance."""
    n = d.nseg
    cnt = np.bincount(d.seg, ww, n)
    qq = np.bincount(d.seg, ww * q * q, n) + 1e-12
    kappa = np.bincount(d.seg, ww * q * r, n) / qq
    rest = r - kappa[d.seg] * q if prm.random_curvature else r  # else a curved segment is a noisy one
    ms = np.bincount(d.seg, ww * rest * rest, n) / np.maximum(cnt - 3, 1)
    valid = cnt > 4
    med = np.median(ms[valid]) if valid.any() else 0.01
    ms = (cnt * ms + prm.shrink * med) / (cnt + prm.shrink)
    return np.maximum(ms, prm.sigma_floor ** 2), kappa, ms / qq


def curvature_spread(kappa: np.ndarray, kappa_var: np.ndarray, ok: np.ndarray, floor: float) -> float:
    """τ²: the typical scene edge's curvature variance beyond its noise, robustly (a few grossly curved or
    mis-joined segments must not set it: medians), at least floor²."""
    if ok.sum() < 3:
        return floor ** 2
    k2, v = kappa[ok] ** 2, kappa_var[ok]

    def excess(tau2: float) -> float:  # median of the standardised squared curvatures, less χ²₁'s median
        return float(np.median(k2 / (tau2 + v))) - 0.455

    lo, hi = floor ** 2, max(floor ** 2, float(k2.max()), 1e-12)
    if excess(lo) <= 0:
        return lo
    for _ in range(40):  # bisection in log τ²
        mid = np.sqrt(max(lo, 1e-12) * hi)
        lo, hi = (mid, hi) if excess(mid) > 0 else (lo, mid)
    return hi


def edge_weights(kappa: np.ndarray, kappa_var: np.ndarray, tau2: float, nu: float) -> np.ndarray:
    """Each segment's weight under Student-t curvatures (ν degrees of freedom): a segment bent far beyond τ
    by the scene (a curved object, two edges joined) loses its say in the field."""
    return (nu + 1.0) / (nu + kappa ** 2 / (tau2 + kappa_var))


def marginal_stats(xt: np.ndarray, yt: np.ndarray, q: np.ndarray, pw: np.ndarray, d: Design, track: np.ndarray,
                   tau2: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """H and g with each track's curvature marginalised (Woodbury), and per track (1/τ² + a)⁻¹ and v − uᵀc's parts."""
    xtw = xt.T * pw
    h, g = xtw @ xt, xtw @ yt
    if tau2 <= 0:
        return h, g, np.zeros(0), np.zeros((0, xt.shape[1] + 1))
    t = track[d.seg]
    nt = int(track.max()) + 1
    a = np.bincount(t, pw * q * q, nt)
    uv = np.stack([np.bincount(t, pw * q * col, nt) for col in np.column_stack([xt, yt]).T], axis=1)  # T × (K+1)
    inv = 1.0 / (1.0 / tau2 + a)
    u, v = uv[:, :-1], uv[:, -1]
    return h - (u.T * inv) @ u, g - (u.T * inv) @ v, inv, uv


def solve(d: Design, prior_var: np.ndarray, prm: SolveParams = SolveParams()) -> Estimate:
    """MAP coefficients under the prior N(0, diag(prior_var)) by IRLS, with H, g and the covariance."""
    k = prior_var.size
    prior = np.diag(1.0 / prior_var)
    if d.y.size < 5 or d.nseg == 0:
        return Estimate(np.zeros(k), np.diag(prior_var), np.zeros((k, k)), np.zeros(k), 0.0, 0, 0)
    n = d.nseg
    track = d.tracks()
    w = np.ones(d.y.size)
    seg_ok = np.ones(n, bool)
    c = np.zeros(k)
    tau2 = 0.0
    both = np.column_stack([d.y, d.x, (d.s / ARC_UNIT) ** 2])
    for it in range(prm.iters + 1):
        ww = w * seg_ok[d.seg]
        t = detrend(both, d, ww)
        yt, xt, q = t[:, 0], t[:, 1:-1], t[:, -1]
        var, kappa, kappa_var = segment_noise(yt - xt @ c, q, d, ww, prm)
        if it < prm.iters:
            med = np.median(var[seg_ok]) if seg_ok.any() else 0.01
            seg_ok = (var <= prm.seg_rms ** 2 * med) & (np.bincount(d.seg, ww, n) >= 5)
        edge = np.ones(n)
        if prm.random_curvature and it >= prm.iters // 2:
            tau2 = curvature_spread(kappa, kappa_var, seg_ok, prm.tau_floor)
            edge = edge_weights(kappa, kappa_var, tau2, prm.nu)
        ww = w * seg_ok[d.seg]
        pw = ww * edge[d.seg] / var[d.seg]
        h, g, inv, uv = marginal_stats(xt, yt, q, pw, d, track, tau2)
        cov = np.linalg.inv(h + prior)
        c = cov @ g
        if it < prm.iters:
            r = yt - xt @ c
            if inv.size:  # each track's curvature at its posterior mean is not an outlier
                r = r - (inv * (uv[:, -1] - uv[:, :-1] @ c))[track[d.seg]] * q
            w = np.minimum(1.0, prm.huber * np.sqrt(var[d.seg]) / np.maximum(np.abs(r), 1e-12))
    used = seg_ok & (np.bincount(d.seg, ww, n) > 0)
    return Estimate(c, cov, h, g, float(np.sqrt(np.median(var[used]))) if used.any() else 0.0, int(used.sum()),
                    int((ww > 0).sum()), float(np.sqrt(tau2)), int(np.unique(track[used]).size))
