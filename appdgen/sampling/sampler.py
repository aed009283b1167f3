"""Sampling perturbed calibrations whose APPD labels are about uniform over [0, appd_max] (% of the diagonal).

Each sample draws its target APPD first, then a random direction in the parameter box (ranges.ParameterBox,
extended to the box's boundary), and solves for the scale λ along that ray whose coarse APPD hits the target
(search.solve_ray, on estimate.CoarseEstimator). Directions that do not reach the target before the box's
boundary, whose search does not converge, or (with labels=True) whose stored label would exceed appd_max are
redrawn; after max_directions of them, the ray to the reachable maximum (reach.largest_appd). The stored label is
the full output grid's, with the exact crop, and depends on the calibration alone. All randomness of sample i
comes from numpy's SeedSequence([seed, i]). The parameters are the reference's lens model's
(Calibration.param_names): fx, fy, cx, cy, then its coefficients.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from appdgen.calib.calibration import Calibration
from appdgen.errors import AppdgenError
from appdgen.geometry.appd import appd_px, px_to_pct
from appdgen.geometry.bend import split_warp
from appdgen.geometry.crop import Crop, check_max_fov, valid_region
from appdgen.geometry.maps import Rectification, rectify
from appdgen.sampling.estimate import CoarseEstimator
from appdgen.sampling.ranges import ParameterBox, Range, default_ranges
from appdgen.sampling.reach import Reach, UnreachableError, largest_appd, quick_reach, unreachable
from appdgen.sampling.search import solve_ray

DEFAULT_APPD_MAX = 1.0  # % of the raw diagonal
CAP_RETRIES = 3  # directions whose label exceeds appd_max before the target is lowered just below it


@dataclass(frozen=True)
class Draw:
    """One sampled calibration with its search bookkeeping (target and estimate in % of the diagonal).

    With Sampler(labels=True), `rect` is its full-size rectification and `appd_px` its stored label (raw px).
    """

    index: int
    calib: Calibration
    is_reference: bool
    target_pct: float
    estimate_pct: float
    evaluations: int
    seconds: float
    rect: Rectification | None = None
    appd_px: float | None = None


@dataclass(frozen=True)
class Label:
    """A drawn calibration's label: APPD in % of the diagonal and raw px, and its rectification (labels=True;
    otherwise the coarse estimate in %, and None)."""

    appd_pct: float
    rect: Rectification | None
    appd_px: float | None


@dataclass
class Sampler:
    """Draws calibrations around a reference so that APPD labels are about uniform over [0, appd_max]."""

    reference: Calibration
    ranges: dict[str, Range] | None = None  # default_ranges(reference)
    appd_max: float = DEFAULT_APPD_MAX
    zero_fraction: float = 0.01
    size: tuple[int, int] | None = None
    tolerance: float = 0.01  # of appd_max: a fifth of a 5 % histogram bin
    max_directions: int = 200
    max_fov: float | None = None  # degrees: bounds the horizontal field of view of every crop
    labels: bool = False  # compute each draw's full-grid label and accept only labels <= appd_max
    _reach: Reach | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        if not (self.appd_max > 0 and math.isfinite(self.appd_max)):
            raise AppdgenError(f"--appd-max {self.appd_max!r}: must be a positive number (% of the diagonal)")
        if not 0 <= self.zero_fraction <= 1:
            raise AppdgenError(f"--zero-fraction {self.zero_fraction!r}: must be in [0, 1]")
        check_max_fov(self.max_fov)
        self.ranges = self.ranges if self.ranges is not None else default_ranges(self.reference)
        self.box = ParameterBox.around(self.reference, self.ranges)
        self._out_size = self.size or self.reference.size
        # The full, guarded crop refuses a reference the lens cannot rectify; the coarse search crops (257 nodes) are
        # estimates whose grid error can pass the guard's 1e-3 px on steep lenses (EUCM, rational), so they skip it.
        reference_crop = self._crop(self.reference)
        self.estimator = CoarseEstimator(self.box, self._out_size, self.max_fov)
        self.reference_rect = rectify(self.reference, self._out_size, reference_crop) if self.labels else None

    def reach(self) -> Reach:
        """About the largest coarse APPD (% of the diagonal) inside the box, and where (searched once)."""
        if self._reach is None:
            self._reach = largest_appd(self.estimator)
        return self._reach

    def check_reachable(self) -> None:
        """Refuse an --appd-max the ranges cannot reach (before anything is written), with the reachable maximum."""
        if quick_reach(self.estimator, self.appd_max):
            return
        largest = self.reach().appd_pct
        if largest < self.appd_max:
            raise unreachable(self.estimator, self.appd_max, largest)

    def draw(self, seed: int, index: int) -> Draw:
        """Sample `index` of a build with this seed: the same calibration whatever the worker or order."""
        start = time.perf_counter()
        rng = np.random.default_rng([seed, index])
        if rng.random() < self.zero_fraction:
            ref = self.reference_rect
            return Draw(index, self.reference, True, 0.0, 0.0, 0, time.perf_counter() - start, ref,
                        0.0 if ref is not None else None)
        target = rng.uniform(0.0, self.appd_max)
        evaluations, capped = 0, 0
        for attempt in range(self.max_directions + 1):
            # After max_directions random rays, the ray to the reachable maximum (which check_reachable vouches for).
            direction = self.box.direction(rng) if attempt < self.max_directions else self.reach().offsets
            solution = solve_ray(self.estimator, direction, target, self.tolerance * self.appd_max)
            evaluations += solution.evaluations
            if solution.found is None:
                continue
            calib, estimate = solution.found.calib, solution.found.appd_pct
            label = self._label(calib, estimate)
            if label is None:
                continue
            if label.appd_pct > self.appd_max:
                capped += 1
                if capped >= CAP_RETRIES:  # the target sits at the very top: aim just below the cap
                    target = min(target, self.appd_max * (1.0 - 2.0 * self.tolerance))
                continue
            return Draw(index, calib, False, target, estimate, evaluations, time.perf_counter() - start, label.rect,
                        label.appd_px)
        raise UnreachableError(
            f"--appd-max {self.appd_max:g}: after {self.max_directions} directions none reached APPD "
            f"{target:.3f} % inside the ranges; lower --appd-max or widen --ranges"
        )

    def _crop(self, calib: Calibration) -> Crop:
        """The full, guarded crop of a calibration under this sampler's field-of-view bound: Θ* and every Θm get
        the same rule."""
        return valid_region(calib, max_fov=self.max_fov)

    def _label(self, calib: Calibration, estimate: float) -> Label | None:
        """The label with the crop's full guard, or None when that guard refuses calib.

        With labels=True the label is the full output grid's APPD and rect its rectification; otherwise the
        coarse estimate stands in for it (and rect, px are None).
        """
        try:
            if not self.labels:
                self._crop(calib)  # the full grid: a search crop's error can exceed the guard's 1e-3 px
                return Label(estimate, None, None)
            rect = rectify(calib, self._out_size, self._crop(calib))
        except AppdgenError:
            return None
        distance = appd_px(self.reference_rect, rect)
        return Label(px_to_pct(distance, self.reference), rect, distance)


#: What a fit may learn of a draw (`python -m train fit --target`), each a length in raw pixels: its APPD (the
#: paper's label) or the non-affine part of its warp (geometry.bend); dataset.layout.TARGETS names their columns.
TARGETS = ("appd", "bend")


def target_px(sampler: Sampler, draw: Draw, target: str) -> float:
    """A labelled draw's value of a fit target (TARGETS), raw pixels: what `appdgen build` writes for the sample."""
    if target == "appd":
        return draw.appd_px
    if target == "bend":
        return split_warp(sampler.reference, sampler.reference_rect.crop, draw.calib, draw.rect.crop).bend_px
    raise AppdgenError(f"--target {target!r}: expected one of {', '.join(TARGETS)}")
