"""The estimator's error model: how much the solve's Gaussian likelihood is tempered (κ) before it weighs the
library, and the least evidence worth a number.

The solve's likelihood treats edge points as independent and the field's basis as exact; on simulation its
errors on the field's coefficients are ~20× (one frame) to ~75× (ten frames) its own variance, and grow with the
frames pooled (errors that do not average out: the basis' truncation, the library's spacing, edges shared by the
scene). κ = KAPPA_FRAME · frames^KAPPA_POWER makes the tempered posterior on the coefficients calibrated (mean
normalised Mahalanobis distance of the true coefficients 1), fitted on training streets by

    appdgen synth --frames 60 --seed 101 --out /tmp/det/train --jobs 1 --quiet
    python benchmarks/detect_error_model.py --frames /tmp/det/train      # 2026-12-03: 48 frames, 8 sequences
      -> calibrated kappa: frame 22.8, sequence (10 frames) 94.4; kappa = 22.8 * frames ** 0.616
"""
from __future__ import annotations

from appdgen.detect.solve import Estimate

#: Fewer segments used by the solve than this: the reading abstains.
MIN_SEGMENTS = 8
KAPPA_FRAME = 22.8  # κ of one frame
KAPPA_POWER = 0.616  # κ's growth with the frames pooled


def kappa(estimate: Estimate, frames: int) -> float:
    """Likelihood tempering for a solve over `frames` frames (unitless, ≥ 1)."""
    return KAPPA_FRAME * max(frames, 1) ** KAPPA_POWER
