"""The coarse APPD estimate a sampler's searches run on: APPD (% of the diagonal) against the reference on a
coarse output grid (midpoint rule), with quick crops (crop.search_region) whose node boxes are predicted around
each calibration's slide box (crop.slide_box) from the reference's, and APPD's slope along a ray at the
reference from the grid positions' Jacobian."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from appdgen.calib.calibration import Calibration
from appdgen.errors import AppdgenError
from appdgen.geometry.crop import search_region, slide_box, valid_region
from appdgen.geometry.distortion import distort_to_pixels
from appdgen.sampling.ranges import ParameterBox

SEARCH_NODES = 257  # the search crops' grid: within ~0.02 output px on KITTI, ~0.4 of the full crop's time
COARSE_COLUMNS = 48  # coarse output grid of the search: 48 × 18 for KITTI


@dataclass(frozen=True)
class Estimate:
    """A calibration and its coarse APPD against the reference (% of the diagonal)."""

    calib: Calibration
    appd_pct: float


class CoarseEstimator:
    """Coarse APPD of calibrations in a parameter box, against its reference, at an output size (pixels)."""

    def __init__(self, box: ParameterBox, size: tuple[int, int], max_fov: float | None) -> None:
        self.box, self.reference, self.max_fov = box, box.reference, max_fov
        w, h = self._out_size = size
        cols = COARSE_COLUMNS
        rows = max(8, round(cols * h / w))
        # Cell centres of a cols × rows partition of the output image, in output pixels (midpoint rule).
        self._grid = np.meshgrid((np.arange(cols) + 0.5) * w / cols - 0.5, (np.arange(rows) + 0.5) * h / rows - 0.5)
        # The search's crops put their nodes on a box predicted around each calibration's slide box (search_region):
        # no frame box per evaluation, which was ~40 % of its cost.
        self.reference_slide_box, self._slide_box_slopes = self._slide_box_model()
        self._ref_points = self._positions(self.reference)
        self._jacobian = self._position_jacobian()

    def estimate(self, calib: Calibration, guard: bool = False) -> float:
        """APPD (% of the diagonal) against the reference on the coarse grid; `guard`: through the full frame box's
        crop with its guard (AppdgenError for a calibration the lens cannot rectify)."""
        distance = np.hypot(*(self._positions(calib, guard) - self._ref_points))
        return float(distance.mean()) * 100.0 / self.reference.diagonal

    def evaluate(self, offsets: np.ndarray) -> Estimate | None:
        """The coarse estimate at offsets from the reference, or None when that calibration is invalid (fold-over)."""
        try:
            calib = self.box.calibration(offsets)
            return Estimate(calib, self.estimate(calib, guard=False))
        except AppdgenError:
            return None

    def slope(self, direction: np.ndarray) -> float:
        """APPD's slope along the ray at λ = 0 (% of the diagonal per unit λ), from the positions' Jacobian."""
        moved = np.tensordot(direction, self._jacobian, axes=1)
        return float(np.hypot(*moved).mean()) * 100.0 / self.reference.diagonal

    def linear_appd(self, offsets: np.ndarray, free: np.ndarray) -> np.ndarray:
        """The linearised coarse APPD (positions' Jacobian; pixels, not %) of rows of offsets of the free
        parameters (n × len(free))."""
        moved = np.tensordot(offsets, self._jacobian[free], axes=1)  # n × 2 × rows × cols
        return np.hypot(moved[:, 0], moved[:, 1]).mean(axis=(1, 2))

    def _slide_box_model(self) -> tuple[np.ndarray, np.ndarray]:
        """The reference's slide box (x0, x1, y0, y1; crop.slide_box) and each side's secant slope per parameter,
        towards its range's low end and towards its high end (P × 2 × 4, normalized per parameter unit)."""
        box = self.box
        ref = np.array(slide_box(self.reference, SEARCH_NODES, self.max_fov))
        slopes = np.zeros((len(box.names), 2, 4))
        for j, ends in enumerate(zip(box.low, box.high, strict=True)):
            for side, end in enumerate(ends):
                if end != 0:
                    step = np.zeros(len(box.names))
                    step[j] = end
                    try:
                        moved = slide_box(box.calibration(step), SEARCH_NODES, self.max_fov)
                    except AppdgenError:  # an invalid end: no slope that way (search_region catches what it misses)
                        continue
                    slopes[j, side] = (np.array(moved) - ref) / end
        return ref, slopes

    def _search_box(self, calib: Calibration) -> tuple[float, float, float, float]:
        """A node box (normalized) about calib's slide box as the reference's and the secant slopes predict it,
        plus 15 % of its size a side (search_region redoes a crop whose slide box reaches the box on its own box)."""
        offsets = self.box.offsets(calib)
        slopes = np.where((offsets < 0)[:, None], self._slide_box_slopes[:, 0], self._slide_box_slopes[:, 1])
        x0, x1, y0, y1 = self.reference_slide_box + offsets @ slopes
        pad_x, pad_y = 0.15 * (x1 - x0), 0.15 * (y1 - y0)
        return (x0 - pad_x, x1 + pad_x, y0 - pad_y, y1 + pad_y)

    def _position_jacobian(self) -> np.ndarray:
        """∂(coarse M̂ positions)/∂(parameter) at the reference, by forward differences (P × 2 × rows × cols)."""
        box = self.box
        jacobian = np.zeros((len(box.names), *self._ref_points.shape))
        for j, width in enumerate(box.high - box.low):
            if width > 0:
                step = np.zeros(len(box.names))
                step[j] = 1e-3 * width
                jacobian[j] = (self._positions(box.calibration(step)) - self._ref_points) / step[j]
        return jacobian

    def _positions(self, calib: Calibration, guard: bool = False) -> np.ndarray:
        """Raw-pixel positions of M̂ at the coarse grid (2 × rows × cols): the search crop's (search_region) unless
        `guard`, or its box may have cut it; then the frame box's."""
        crop = search_region(calib, self._search_box(calib), SEARCH_NODES, self.max_fov) if not guard else None
        crop = crop or valid_region(calib, SEARCH_NODES, guard, max_fov=self.max_fov)
        k = crop.camera_matrix(self._out_size)
        gx, gy = self._grid
        return np.stack(distort_to_pixels((gx - k[0, 2]) / k[0, 0], (gy - k[1, 2]) / k[1, 1], calib))
