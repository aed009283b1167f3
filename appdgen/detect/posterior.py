"""From the solve to APPD, bend and parameter offsets with their uncertainty: a posterior over the library's draws
(the sampling prior), each weighted by the solve's likelihood of its field coefficients, tempered by the error model.

The Gaussian likelihood of the solve, log L(c) = gᵀc − ½ cᵀHc, treats edge points as independent; real residuals
are correlated along a segment and scenes have curved edges, so it is over-confident. The error model
(appdgen.detect.errormodel) tempers it by κ, fitted on simulation.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from appdgen.detect.model import FieldModel


@dataclass(frozen=True)
class Posterior:
    """Posterior means and sds over the library (APPD and bend in % of the raw diagonal; offsets in parameter
    units), the probability that APPD exceeds the threshold, and the effective number of draws it rests on."""

    appd: float
    appd_sd: float
    bend: float
    bend_sd: float
    p_above: float
    offsets: np.ndarray
    offsets_sd: np.ndarray
    c: np.ndarray
    effective: float


def library_weights(model: FieldModel, h: np.ndarray, g: np.ndarray, kappa: float) -> np.ndarray:
    """Normalised weights of the library's draws: exp((gᵀc − ½cᵀHc)/κ)."""
    coefs = model.coefs
    ll = (coefs @ g - 0.5 * np.einsum("ij,jk,ik->i", coefs, h, coefs)) / kappa
    w = np.exp(ll - ll.max())
    return w / w.sum()


def effective(w: np.ndarray) -> float:
    """Effective number of draws of normalised weights (Kish)."""
    return float(1.0 / (w ** 2).sum())


def tempered_weights(model: FieldModel, h: np.ndarray, g: np.ndarray, kappa: float, least: float
                     ) -> tuple[np.ndarray, float]:
    """Library weights at tempering κ, raised (bisection in log κ) until at least `least` draws carry them: a
    posterior sharper than the library's spacing would rest on one draw's accidents (its shift, its crop)."""
    w = library_weights(model, h, g, kappa)
    if effective(w) >= least:
        return w, kappa
    lo, hi = np.log(kappa), np.log(kappa) + 20.0
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        if effective(library_weights(model, h, g, np.exp(mid))) >= least:
            hi = mid
        else:
            lo = mid
    return library_weights(model, h, g, np.exp(hi)), float(np.exp(hi))


def informative_axes(model: FieldModel, h: np.ndarray, kappa: float, most: int) -> np.ndarray:
    """(K, m) directions of c where the tempered data outweigh the prior (information > prior precision), most
    informative first, at most `most`."""
    root = np.sqrt(model.var)
    evals, evecs = np.linalg.eigh(root[:, None] * h * root[None, :] / kappa)
    order = np.argsort(evals)[::-1][:most]
    order = order[evals[order] > 1.0]
    return root[:, None] * evecs[:, order]  # back from prior-whitened coordinates


def adjusted(values: np.ndarray, coefs: np.ndarray, w: np.ndarray, c: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """Values (n, M) moved to the solve's c along the informative axes by their weighted local-linear regression
    there (regression adjustment, Beaumont et al. 2002): the library is too sparse for its nearest draws to sit
    where the data say, and elsewhere the prior's spread is the answer."""
    if axes.shape[1] == 0:
        return values
    metric = np.linalg.pinv(axes)  # coordinates along the axes
    z = (coefs - c) @ metric.T
    zc = z - w @ z
    zw = zc.T * w
    gram = zw @ zc
    gram += 1e-6 * np.trace(gram) / len(gram) * np.eye(len(gram))
    slope = np.linalg.solve(gram, zw @ (values - w @ values))
    return values - z @ slope


def _mean_sd(w: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean and sd of x (n,) or (n, P)."""
    m = w @ x
    return m, np.sqrt(np.maximum(w @ (x - m) ** 2, 0.0))


def posterior(model: FieldModel, h: np.ndarray, g: np.ndarray, kappa: float, threshold_pct: float,
              c: np.ndarray | None = None, least: float = 1.0, axes: int = 4) -> Posterior:
    """The library's posterior under the tempered likelihood (at least `least` effective draws); with c (the
    solve's MAP) the draws' labels are regression-adjusted to it."""
    w, used = tempered_weights(model, h, g, kappa, least)
    values = np.column_stack([model.appd, model.bend, model.offsets])
    if c is not None:
        values = adjusted(values, model.coefs, w, c, informative_axes(model, h, used, axes))
        values[:, :2] = np.maximum(values[:, :2], 0.0)  # lengths
    mean, sd = _mean_sd(w, values)
    return Posterior(float(mean[0]), float(sd[0]), float(mean[1]), float(sd[1]),
                     float(w[values[:, 0] > threshold_pct].sum()), mean[2:], sd[2:], w @ model.coefs, effective(w))
