"""The robust solve for the field's coefficients from edge points, pooled over any number of frames in one solve.

Along a segment, points p_i = base_i + e_i·n of a straight scene edge have p_i + f(p_i) collinear, f = μ + Σ c_k B_k
the field (output px): y_i = e_i + n·μ(p_i) = a + b·s_i − Σ c_k n·B_k(p_i) (+ noise). The segment's own line (a, b)
is a nuisance removed by a weighted per-segment detrend of y and of the design X = −n·B; c is solved by iteratively
reweighted least squares (each segment weighted by its own noise, shrunk towards the median; Huber on points;
segments far noisier than the median dropped) with the library's prior on c. Out: the MAP c, its covariance, and the
likelihood's sufficient statistics H = XᵀWX, g = XᵀWy for the posterior over the library.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from appdgen.detect.edges import segment_fit


@dataclass(frozen=True)
class Design:
    """Observations of one or more frames: y (N,), X (N, K), arc position s (N,), segment index (N,), nseg."""

    y: np.ndarray
    x: np.ndarray
    s: np.ndarray
    seg: np.ndarray
    nseg: int


def pool(designs: list[Design]) -> Design:
    """Designs of several frames stacked, segments renumbered (each keeps its own nuisance line)."""
    offsets = np.cumsum([0] + [d.nseg for d in designs])
    return Design(np.concatenate([d.y for d in designs]), np.vstack([d.x for d in designs]),
                  np.concatenate([d.s for d in designs]),
                  np.concatenate([d.seg + o for d, o in zip(designs, offsets)]), int(offsets[-1]))


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


def detrend(z: np.ndarray, d: Design, w: np.ndarray) -> np.ndarray:
    """z (N,) or (N, K) minus its weighted least-squares line in s per segment."""
    return z - segment_fit(d.s, z, d.seg, w, d.nseg, 1)


def solve(d: Design, prior_var: np.ndarray, prm: SolveParams = SolveParams()) -> Estimate:
    """MAP coefficients under the prior N(0, diag(prior_var)) by IRLS, with H, g and the covariance."""
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
        r = yt - xt @ c
        cnt = np.bincount(d.seg, ww, n)
        ms = np.bincount(d.seg, ww * r * r, n) / np.maximum(cnt - 2, 1)
        valid = seg_ok & (cnt > 3)
        med = np.median(ms[valid]) if valid.any() else 0.01
        ms = (cnt * ms + prm.shrink * med) / (cnt + prm.shrink)
        sig = np.maximum(np.sqrt(ms), prm.sigma_floor)
        if it < prm.iters:
            seg_ok = (np.sqrt(ms) <= prm.seg_rms * np.sqrt(med)) & (cnt >= 5)
        ww = w * seg_ok[d.seg]
        pw = ww / sig[d.seg] ** 2
        xtw = xt.T * pw
        h, g = xtw @ xt, xtw @ yt
        cov = np.linalg.inv(h + prior)
        c = cov @ g
        if it < prm.iters:
            r = yt - xt @ c
            w = np.minimum(1.0, prm.huber * sig[d.seg] / np.maximum(np.abs(r), 1e-12))
    return Estimate(c, cov, h, g, float(np.median(sig[seg_ok])) if seg_ok.any() else 0.0, int(seg_ok.sum()),
                    int((ww > 0).sum()))
