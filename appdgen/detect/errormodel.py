"""The estimator's error model: how much the solve's Gaussian likelihood is tempered (κ) before it weighs the
library, and the least evidence worth a number. Constants fitted on simulation by benchmarks/detect_error_model.py
(the command and date beside each)."""
from __future__ import annotations

from appdgen.detect.solve import Estimate

#: Fewer segments used by the solve than this: the reading abstains.
MIN_SEGMENTS = 8
#: κ of the straightness probe (../shared/bench), tuned on training streets: the starting point.
KAPPA = 30.0


def kappa(estimate: Estimate, frames: int) -> float:
    """Likelihood tempering for a solve over `frames` frames (unitless, ≥ 1)."""
    return KAPPA
