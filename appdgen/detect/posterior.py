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


def _mean_sd(w: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean and sd of x (n,) or (n, P)."""
    m = w @ x
    return m, np.sqrt(np.maximum(w @ (x - m) ** 2, 0.0))


def posterior(model: FieldModel, h: np.ndarray, g: np.ndarray, kappa: float, threshold_pct: float) -> Posterior:
    """The library's posterior under the likelihood tempered by κ."""
    w = library_weights(model, h, g, kappa)
    values = np.column_stack([model.appd, model.bend, model.offsets])
    mean, sd = _mean_sd(w, values)
    return Posterior(float(mean[0]), float(sd[0]), float(mean[1]), float(sd[1]),
                     float(w[model.appd > threshold_pct].sum()), mean[2:], sd[2:], w @ model.coefs, effective(w))
