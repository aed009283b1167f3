"""The robust solve for the field's coefficients from edge points, pooled over any number of frames in one solve.

Along a segment, points p_i = base_i + e_i·n of a straight scene edge have p_i + f(p_i) collinear, f = μ + Σ c_k B_k
the field (output px): y_i = e_i + n·μ(p_i) = a + b·s_i − Σ c_k n·B_k(p_i) (+ noise). The segment's own line (a, b)
is a nuisance removed by a weighted per-segment detrend of y and of the design X = −n·B; c is solved by iteratively
reweighted least squares (each segment weighted by its own noise, shrunk towards the median; Huber on points;
segments far noisier than the median dropped) with the library's prior on c. Out: the MAP c, its covariance, and the
likelihood's sufficient statistics H = XᵀWX, g = XᵀWy for the posterior over the library.

Points are not independent: a scene edge is seen in many frames (a track, appdgen.detect.tracks) and its points
share its own curvature. The solve keeps the independent-points H and g, and also returns the score's spread over
scene edges (the meat of a sandwich estimate, clustered by track) for the error model (appdgen.detect.errormodel).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from appdgen.detect.edges import segment_fit


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
                  np.concatenate([d.seg + o for d, o in zip(designs, offsets[:-1], strict=True)]),
                  int(offsets[-1]), track)


@dataclass(frozen=True)
class SolveParams:
    """The robust solve's settings (px where a length)."""

    huber: float = 1.0  # points beyond huber × their segment's sigma are down-weighted
    seg_rms: float = 2.5  # segments whose sigma exceeds seg_rms × the median are dropped
    sigma_floor: float = 0.02  # no segment is trusted more than this
    shrink: float = 20.0  # points' worth of the median variance mixed into each segment's own
    iters: int = 6


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
    tracks: int = 0  # scene edges the used segments belong to
    meat: np.ndarray | None = None  # (K, K) Σ_t s_t s_tᵀ of the likelihood's score summed per scene edge
    seg_weight: np.ndarray | None = None  # (nseg,) each segment's share of the information (trace of its H)


def detrend(z: np.ndarray, d: Design, w: np.ndarray, degree: int = 1) -> np.ndarray:
    """z (N,) or (N, K) minus its weighted least-squares polynomial in s per segment."""
    return z - segment_fit(d.s, z, d.seg, w, d.nseg, degree)


def segment_noise(r: np.ndarray, d: Design, ww: np.ndarray, prm: SolveParams) -> np.ndarray:
    """Each segment's noise variance from its residual r, shrunk towards the median (px²)."""
    n = d.nseg
    cnt = np.bincount(d.seg, ww, n)
    ms = np.bincount(d.seg, ww * r * r, n) / np.maximum(cnt - 3, 1)
    valid = cnt > 4
    med = np.median(ms[valid]) if valid.any() else 0.01
    ms = (cnt * ms + prm.shrink * med) / (cnt + prm.shrink)
    return np.maximum(ms, prm.sigma_floor ** 2)


def solve(d: Design, prior_var: np.ndarray, prm: SolveParams = SolveParams()) -> Estimate:
    """MAP coefficients under the prior N(0, diag(prior_var)) by IRLS, with H, g, the covariance and the meat."""
    k = prior_var.size
    prior = np.diag(1.0 / prior_var)
    if d.y.size < 5 or d.nseg == 0:
        return Estimate(np.zeros(k), np.diag(prior_var), np.zeros((k, k)), np.zeros(k), 0.0, 0, 0)
    n = d.nseg
    w = np.ones(d.y.size)
    seg_ok = np.ones(n, bool)
    c = np.zeros(k)
    both = np.column_stack([d.y, d.x])
    for it in range(prm.iters + 1):
        ww = w * seg_ok[d.seg]
        t = detrend(both, d, ww)
        yt, xt = t[:, 0], t[:, 1:]
        var = segment_noise(yt - xt @ c, d, ww, prm)
        if it < prm.iters:
            med = np.median(var[seg_ok]) if seg_ok.any() else 0.01
            seg_ok = (var <= prm.seg_rms ** 2 * med) & (np.bincount(d.seg, ww, n) >= 5)
        ww = w * seg_ok[d.seg]
        pw = ww / var[d.seg]
        xtw = xt.T * pw
        h, g = xtw @ xt, xtw @ yt
        cov = np.linalg.inv(h + prior)
        c = cov @ g
        r = yt - xt @ c
        if it < prm.iters:
            w = np.minimum(1.0, prm.huber * np.sqrt(var[d.seg]) / np.maximum(np.abs(r), 1e-12))
    used = seg_ok & (np.bincount(d.seg, ww, n) > 0)
    track = d.tracks()
    info = np.bincount(d.seg, pw * (xt ** 2).sum(1), n)
    return Estimate(c, cov, h, g, float(np.sqrt(np.median(var[used]))) if used.any() else 0.0, int(used.sum()),
                    int((ww > 0).sum()), int(np.unique(track[used]).size), edge_meat(xt, r, pw, track[d.seg]),
                    info / max(float(info.sum()), 1e-300))


def edge_meat(xt: np.ndarray, r: np.ndarray, pw: np.ndarray, cluster: np.ndarray) -> np.ndarray:
    """(K, K) Σ_t s_t s_tᵀ with s_t = Σ_{i∈t} pw_i r_i x_i: the score's spread over scene edges (the sandwich's
    meat, clustered so that the points of one edge, in every frame it is seen, count as one observation)."""
    nt = int(cluster.max()) + 1 if cluster.size else 0
    score = np.stack([np.bincount(cluster, pw * r * col, nt) for col in xt.T], axis=1) if nt else np.zeros(
        (0, xt.shape[1]))
    return score.T @ score
