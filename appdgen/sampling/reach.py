"""Reachability: about the largest coarse APPD inside a parameter box, and the refusal of an --appd-max beyond it
(before anything is written)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from appdgen.errors import AppdgenError
from appdgen.sampling.estimate import CoarseEstimator

QUICK_RAYS = 8  # rays check_reachable tries before searching for the maximum
REACH_RAYS = 64  # random rays of the reachability search (plus 4 corners and coordinate ascent)


class UnreachableError(AppdgenError):
    """The ranges cannot reach a target APPD: an option problem, fixed by other options (and --overwrite)."""


@dataclass(frozen=True, eq=False)
class Reach:
    """About the largest coarse APPD in a box (% of the diagonal) and the offsets where it was found."""

    appd_pct: float
    offsets: np.ndarray


def quick_reach(estimator: CoarseEstimator, appd_max: float) -> bool:
    """Whether one of QUICK_RAYS of the sampler's own rays reaches appd_max (usually one does: no search needed)."""
    rng = np.random.default_rng(0)
    for _ in range(QUICK_RAYS):
        point = estimator.evaluate(estimator.box.direction(rng))
        if point is not None and point.appd_pct >= appd_max:
            return True
    return False


def largest_appd(estimator: CoarseEstimator) -> Reach:
    """About the largest coarse APPD inside the estimator's box, and where.

    A cheap search: REACH_RAYS of the sampler's own rays (to the box's boundary) and the four corners the
    linearised APPD ranks first, then coordinate ascent moving one parameter at a time to its low end, 0 or
    its high end. APPD need not peak at a corner: the crop reacts to the parameters together.
    """
    box = estimator.box
    free = box.free()
    rng = np.random.default_rng(0)
    choice = (np.arange(2 ** free.size)[:, None] >> np.arange(free.size)) & 1 if free.size <= 12 else \
        rng.integers(0, 2, (4096, free.size))
    corners = np.where(choice == 1, box.high[free], box.low[free])
    linear = estimator.linear_appd(corners, free)
    starts = [box.direction(rng) for _ in range(REACH_RAYS)]
    for c in np.argsort(-linear, kind="stable")[:4]:
        starts.append(np.zeros(len(box.names)))
        starts[-1][free] = corners[c]
    best = Reach(0.0, np.zeros(len(box.names)))
    for trial in starts:
        best = _better(estimator, trial, best)
    for _ in range(3):
        start = best.appd_pct
        for j in free:
            for value in (box.low[j], 0.0, box.high[j]):
                trial = best.offsets.copy()
                trial[j] = value
                best = _better(estimator, trial, best)
        if best.appd_pct <= start:
            break
    return best


def unreachable(estimator: CoarseEstimator, appd_max: float, largest: float) -> UnreachableError:
    """The refusal of an --appd-max above the reachable maximum `largest` (both % of the diagonal)."""
    why = ""
    if not any(estimator.reference.coeffs):
        why = (" (without lens distortion a focal or principal-point change moves the crop with the image, "
               "so only the coefficients' ranges give APPD)")
    return UnreachableError(f"--appd-max {appd_max:g}: the largest APPD inside these ranges is about "
                            f"{largest:.3g} % of the diagonal{why}; lower --appd-max or widen --ranges")


def _better(estimator: CoarseEstimator, trial: np.ndarray, best: Reach) -> Reach:
    """The trial when it is valid and beats the best so far, else the best so far."""
    point = estimator.evaluate(trial) if not np.array_equal(trial, best.offsets) else None
    return Reach(point.appd_pct, trial) if point is not None and point.appd_pct > best.appd_pct else best
