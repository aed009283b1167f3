"""From the reading's likelihood to APPD, bend and parameter offsets with their uncertainty: a posterior over the
library's draws (the sampling prior) and the scene term (errormodel). Its means are a kernel regression over the
library, smooth in the reading; the scene term's floor keeps its kernel from narrowing onto one draw."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from appdgen.detect.errormodel import Likelihood
from appdgen.detect.model import FieldModel


@dataclass(frozen=True)
class Posterior:
    """Posterior means and sds (APPD and bend in % of the raw diagonal; offsets in parameter units), the
    probability that APPD exceeds the threshold, the coefficients' posterior mean and the scene term's φ."""

    appd: float
    appd_sd: float
    bend: float
    bend_sd: float
    p_above: float
    offsets: np.ndarray
    offsets_sd: np.ndarray
    c: np.ndarray
    phi: float


def posterior(model: FieldModel, like: Likelihood, threshold_pct: float) -> Posterior:
    """Means and sds of the library's labels under the posterior over (draw, scene term)."""
    w = np.exp(like.log - like.log.max())
    w = w / w.sum()
    draw = w.sum(0)
    values = model.targets
    mean = draw @ values
    sd = np.sqrt(np.maximum(draw @ (values - mean) ** 2, 0.0))
    return Posterior(float(mean[0]), float(sd[0]), float(mean[1]), float(sd[1]),
                     float(draw[model.appd > threshold_pct].sum()), mean[2:], sd[2:], draw @ model.coefs,
                     float(w.sum(1) @ like.phis))
