"""The plumb-line floor: a miscalibration detector from line curvature and a ridge fit (the trainer's
--model plumbline, studies.detector's floor arms).

A rectification with the wrong calibration leaves a smooth non-affine warp in the image, which bends the scene's
straight edges. line_features measures that bend on appdgen.detect.edges' evidence (LSD segments joined along
collinear pieces, their edge points refined to sub-pixel along the normal), with lengths scaled to the image
(edge_params), and from each segment's quadratic through its points (detect.edges.segment_coefficients)

- its bulge: the middle's distance from the chord, signed positive away from the image centre (a radial error
  bows lines away from or towards the centre, more the further out);
- the radial coefficient k (a field k·(x, y)·ρ² in centred coordinates of diagonal units) that best explains all
  bulges, robustly weighted, and the mean length of that field's non-affine part: an estimate of the label's bend.

Lengths are in units of the image diagonal, so features compare across output sizes. A shift or zoom (the label's
affine part) leaves lines straight: this floor sees bend, and APPD only as far as bend goes with it. PlumbLine
standardises the features (median, MAD, clipped) and fits a ridge regression in closed form. numpy and OpenCV
only: importing this never imports torch.
"""
from __future__ import annotations

import functools
import json
import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from appdgen.detect.edges import EdgeParams, EdgePoints, edge_points, segment_coefficients
from appdgen.errors import AppdgenError
from appdgen.geometry.bend import affine_rest

#: LSD reads the image at LSD_SCALE, or at most DETECT_WIDTH pixels wide: long edges survive, texture fragments
#: less, and it is faster; the edge points are still refined on the full-resolution gradient.
DETECT_WIDTH = 720
LSD_SCALE = 0.8
#: A (joined) segment counts when at least this long (fraction of the image diagonal, and pixels).
MIN_LENGTH = 0.035
MIN_LENGTH_PX = 10.0
MAX_SEGMENTS = 240  # the longest ones; more add little and cost time
#: Edge points along a segment: one every min length / POINTS_PER_MIN_LENGTH, between MIN_STEP_PX and the
#: edge evidence's own step (3 px).
POINTS_PER_MIN_LENGTH = 16
MIN_STEP_PX = 0.5
SMALLEST_SIDE = 16  # pixels: a smaller image has no measurable lines; its features are zeros
#: Diagonals: how far the principal point may sit from the image centre. Using the reference crop's own principal
#: point instead ranked bend no better, so the image centre stays: it needs no calibration.
CENTRE_SPREAD = 0.05
CAUCHY = 2.0  # the reweighting's scale, in standard errors of a segment's own k
ROUNDS = 3
NOISE_FLOOR = 0.05  # pixels: no edge position is trusted closer than this (a clean synthetic edge fits to ~0)
GRID = (48, 18)  # columns, rows of the grid the radial field's non-affine part is averaged on

#: The vector's entries: the mean length of the non-affine part of the radial field the lines' bulges point to, in %
#: of the diagonal (an estimate of bend_pct), its signed coefficient k, and log(1 + Σ (lever / noise)²): how
#: firmly the scene's lines pin k down. Richer vectors (segment counts, edge noise, bulge and curvature statistics
#: binned by distance from the centre, a decentred plumb-line field, the vanishing point) ranked bend worse after
#: the same ridge fit on the same frames, and the linear floor must work from a few dozen images.
FEATURE_NAMES: tuple[str, ...] = ("radial_bend", "radial_k1", "radial_support")
FEATURES: int = len(FEATURE_NAMES)
#: The saved detector's format: /2 since the features are read off detect.edges' evidence (a /1 ridge was fitted
#: on another profile's features and would mispredict on these).
FORMAT = "appdgen.plumbline/2"


def _grey(image: np.ndarray) -> np.ndarray:
    """The image as uint8 grey levels (H×W), from uint8 H×W grey, H×W×1 or H×W×3 BGR."""
    image = np.asarray(image)
    if image.ndim == 3 and image.shape[2] == 3:
        image = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_BGR2GRAY)
    elif image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim != 2:
        raise AppdgenError(f"plumb-line features need an H×W grey or H×W×3 BGR image, got shape {image.shape}")
    if image.dtype != np.uint8:
        raise AppdgenError(f"plumb-line features need a uint8 image, got {image.dtype}")
    return np.ascontiguousarray(image)


def edge_params(width: int, height: int) -> EdgeParams:
    """detect.edges' parameters for an image of this size (pixels): LSD at LSD_SCALE of at most DETECT_WIDTH
    pixels, segments of MIN_LENGTH diagonals (MIN_LENGTH_PX at least), points closer on smaller images."""
    base = EdgeParams()
    min_len = max(MIN_LENGTH * math.hypot(width, height), MIN_LENGTH_PX)
    return EdgeParams(lsd_scale=LSD_SCALE * min(1.0, DETECT_WIDTH / width), min_len=min_len,
                      piece_len=min(base.piece_len, min_len),
                      step=float(np.clip(min_len / POINTS_PER_MIN_LENGTH, MIN_STEP_PX, base.step)))


@dataclass(frozen=True)
class Bulges:
    """Per segment (S): the bulge of its fitted quadratic (pixels, outward positive), the points' residual RMS about
    it (pixels), its distance from the image centre and the half-span of its points (pixels)."""

    bulge: np.ndarray
    rms: np.ndarray
    distance: np.ndarray
    half: np.ndarray


def bulges(points: EdgePoints, centre: np.ndarray) -> Bulges:
    """Each segment's quadratic through its edge points (offset e against arc position s in half-spans,
    detect.edges), read as a bulge away from `centre` (pixels) over the half-span of its points."""
    nseg, half = points.segments, points.length / 2
    t = points.s / np.maximum(half, 1e-9)[points.seg]  # −1…1 over a segment's points: a well-scaled fit
    coef = segment_coefficients(t, points.e, points.seg, np.ones_like(t), nseg, 2)
    residual = points.e - np.einsum("nd,nd->n", np.stack([np.ones_like(t), t, t * t], axis=1), coef[points.seg])
    count = np.bincount(points.seg, minlength=nseg)
    rms = np.sqrt(np.bincount(points.seg, residual ** 2, nseg) / np.maximum(count - 3, 1))
    across = np.einsum("sk,sk->s", points.normal, points.centre - centre)
    outward = np.where(across < 0, -1.0, 1.0)
    return Bulges(-outward * coef[:, 2], rms, np.abs(across), half)


def radial_k1(bulge: np.ndarray, rms: np.ndarray, lever: np.ndarray, distance: np.ndarray) -> float:
    """The radial coefficient k (field k·(x, y)·ρ², diagonal units) the bulges point to: a straight line at
    distance d from the centre, sampled over half-length h, bulges outward by k·d·h² (`lever`, pixels per unit k).
    Each segment's own k (bulge / lever) counts with its precision (lever / noise)², less near the centre
    (`distance` from it, diagonal units). Their weighted median starts a Cauchy-weighted mean (scale CAUCHY
    standard errors): a few lines the scene did not draw straight, or whose edge was misread, must not move it."""
    # The distortion centre is the principal point, not the image centre: a line passing within CENTRE_SPREAD of
    # the centre has a lever too uncertain to count (road edges through the vanishing point), so it counts less.
    precision = lever ** 2 / (rms ** 2 + NOISE_FLOOR ** 2) * distance ** 2 / (distance ** 2 + CENTRE_SPREAD ** 2)
    if precision.sum() <= 0:
        return 0.0
    own = bulge / np.maximum(lever, 1e-30)
    order = np.argsort(own)
    cumulative = np.cumsum(precision[order])
    k = float(own[order][np.searchsorted(cumulative, cumulative[-1] / 2)])
    for _ in range(ROUNDS):
        weight = precision / (1 + (own - k) ** 2 * precision / CAUCHY ** 2)
        k = float((weight * own).sum() / weight.sum())
    return k


@functools.lru_cache(maxsize=64)
def radial_unit_bend(aspect: float) -> float:
    """Mean length (diagonal units) of the non-affine part of the field (x, y)·ρ² over an image of this aspect,
    in centred coordinates of diagonal units: what k = 1 bends."""
    half_w, half_h = aspect / math.hypot(aspect, 1) / 2, 1 / math.hypot(aspect, 1) / 2
    columns, rows = np.linspace(-half_w, half_w, GRID[0]), np.linspace(-half_h, half_h, GRID[1])
    x, y = (a.ravel() for a in np.meshgrid(columns, rows))
    rho2 = x * x + y * y
    rest = affine_rest(x, y, x * rho2, y * rho2)
    return float(np.hypot(rest.rest_u, rest.rest_v).mean())


def longest(points: EdgePoints, count: int) -> EdgePoints:
    """The `count` longest segments of the evidence (all when fewer), renumbered longest first."""
    if points.segments <= count:
        return points
    keep = np.argsort(-points.length, kind="stable")[:count]
    new = np.full(points.segments, -1)
    new[keep] = np.arange(len(keep))
    mask = new[points.seg] >= 0
    return EdgePoints(points.u[mask], points.v[mask], points.s[mask], points.e[mask], new[points.seg[mask]],
                      points.normal[keep], points.centre[keep], points.length[keep], points.contrast[keep])


def line_features(image: np.ndarray) -> np.ndarray:
    """The plumb-line feature vector of one rectified image (FEATURES float64, lengths in units of its diagonal;
    FEATURE_NAMES says which is which); zeros where the image shows no long lines."""
    grey = _grey(image)
    features = np.zeros(FEATURES)
    height, width = grey.shape
    if min(height, width) < SMALLEST_SIDE:
        return features
    points = longest(edge_points(grey, edge_params(width, height)), MAX_SEGMENTS)
    if points.segments == 0:
        return features
    diagonal = math.hypot(width, height)
    seen = bulges(points, np.array([(width - 1) / 2, (height - 1) / 2]))
    lever = seen.distance * seen.half ** 2 / diagonal ** 2  # pixels of bulge per unit k
    k = radial_k1(seen.bulge, seen.rms, lever, seen.distance / diagonal)
    support = float(np.sum(lever ** 2 / (seen.rms ** 2 + NOISE_FLOOR ** 2)))
    features[:] = [100 * abs(k) * radial_unit_bend(width / height), k, math.log1p(support)]
    return np.nan_to_num(features, nan=0.0, posinf=0.0, neginf=0.0)


def feature_matrix(images: Iterable[np.ndarray]) -> np.ndarray:
    """line_features of every image, stacked (N×FEATURES)."""
    rows = [line_features(image) for image in images]
    return np.array(rows).reshape(len(rows), FEATURES)


#: The alphas fit(alpha=None) chooses among by K-fold cross-validation.
ALPHAS = tuple(10.0 ** (e / 2) for e in range(-2, 9))  # 0.1 … 10⁴
FOLDS = 5
CLIP = 3.0  # robust standard deviations


@dataclass
class PlumbLine:
    """Ridge regression of a target (e.g. APPD or bend in %) on standardised line_features."""

    mean: np.ndarray | None = None
    scale: np.ndarray | None = None
    weights: np.ndarray | None = None
    intercept: float = 0.0
    alpha: float = 1.0

    def fit(self, images: Iterable[np.ndarray], targets: np.ndarray, alpha: float | None = 1.0) -> "PlumbLine":
        """Fit on images and their targets; alpha None picks it by FOLDS-fold cross-validation among ALPHAS."""
        return self.fit_features(feature_matrix(images), targets, alpha)

    def fit_features(self, x: np.ndarray, targets: np.ndarray, alpha: float | None = 1.0) -> "PlumbLine":
        """fit on a precomputed feature matrix (N×FEATURES)."""
        x, y = np.asarray(x, np.float64), np.asarray(targets, np.float64).ravel()
        if x.ndim != 2 or x.shape[1] != FEATURES or len(x) != len(y):
            raise AppdgenError(f"plumb-line fit: {x.shape} features for {y.shape} targets (need N×{FEATURES} and N)")
        if len(y) < 2:
            raise AppdgenError(f"plumb-line fit needs at least 2 images, got {len(y)}")
        self.alpha = float(alpha) if alpha is not None else _cross_validated_alpha(x, y)
        self.mean, self.scale = _centre_and_spread(x)
        self.weights, self.intercept = _ridge(_standardise(x, self.mean, self.scale), y, self.alpha)
        return self

    def predict(self, images: Iterable[np.ndarray]) -> np.ndarray:
        """Predicted targets (the fitted units, ≥ 0) of images."""
        return self.predict_features(feature_matrix(images))

    def predict_features(self, x: np.ndarray) -> np.ndarray:
        """predict on a precomputed feature matrix (N×FEATURES)."""
        if self.weights is None:
            raise AppdgenError("plumb-line detector: predict before fit (or load)")
        x = np.asarray(x, np.float64).reshape(-1, FEATURES)
        return np.maximum(_standardise(x, self.mean, self.scale) @ self.weights + self.intercept, 0.0)

    def to_dict(self) -> dict:
        """JSON-safe form (from_dict reads it back)."""
        if self.weights is None:
            raise AppdgenError("plumb-line detector: nothing fitted to save")
        return {"format": FORMAT, "features": list(FEATURE_NAMES), "mean": self.mean.tolist(),
                "scale": self.scale.tolist(), "weights": self.weights.tolist(), "intercept": self.intercept,
                "alpha": self.alpha}

    @classmethod
    def from_dict(cls, data: dict) -> "PlumbLine":
        """The detector to_dict wrote; refuses another format or feature list."""
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            found = data.get("format") if isinstance(data, dict) else None
            raise AppdgenError(f"not a plumb-line detector (format {found!r}, expected {FORMAT})")
        if list(data.get("features", [])) != list(FEATURE_NAMES):
            raise AppdgenError("plumb-line detector: its feature list differs from this version's")
        try:
            arrays = [np.array(data[key], np.float64) for key in ("mean", "scale", "weights")]
            intercept, alpha = float(data["intercept"]), float(data["alpha"])
        except (KeyError, TypeError, ValueError) as exc:
            raise AppdgenError(f"plumb-line detector: bad field ({exc})") from None
        if any(a.shape != (FEATURES,) for a in arrays):
            raise AppdgenError(f"plumb-line detector: mean, scale and weights must hold {FEATURES} numbers each")
        return cls(*arrays, intercept, alpha)

    def save(self, path: str | Path) -> None:
        """Write the detector as JSON."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=1), encoding="utf-8")

    @classmethod
    def load(cls, path: str | Path) -> "PlumbLine":
        """Read a detector save wrote."""
        try:
            data = json.loads(Path(path).read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise AppdgenError(f"{path}: cannot read a plumb-line detector ({exc})") from None
        return cls.from_dict(data)


def _centre_and_spread(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per feature: median and 1.4826·MAD (the standard deviation of a normal sample, unmoved by the few images
    whose lines mislead the detector), the spread floored at 1e-12."""
    centre = np.median(x, axis=0)
    return centre, np.maximum(1.4826 * np.median(np.abs(x - centre), axis=0), 1e-12)


def _standardise(x: np.ndarray, mean: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Features in standard deviations of the training set, clipped at ±CLIP: one odd image (a scene whose lines
    the detector misreads) must not swing a prediction or a fold's fit."""
    return np.clip((x - mean) / scale, -CLIP, CLIP)


def _ridge(z: np.ndarray, y: np.ndarray, alpha: float) -> tuple[np.ndarray, float]:
    """Closed-form ridge on standardised features: (weights, intercept); the intercept is not penalised."""
    z_mean, y_mean = z.mean(axis=0), float(y.mean())
    centred = z - z_mean
    weights = np.linalg.solve(centred.T @ centred + alpha * np.eye(z.shape[1]), centred.T @ (y - y_mean))
    return weights, y_mean - float(z_mean @ weights)


def _cross_validated_alpha(x: np.ndarray, y: np.ndarray) -> float:
    """The ALPHAS value with the least mean absolute error over FOLDS interleaved folds (each standardised on its
    own training part)."""
    folds = np.arange(len(y)) % min(FOLDS, len(y))
    errors = []
    for alpha in ALPHAS:
        total = 0.0
        for k in np.unique(folds):
            train, test = folds != k, folds == k
            mean, scale = _centre_and_spread(x[train])
            weights, intercept = _ridge(_standardise(x[train], mean, scale), y[train], alpha)
            predicted = np.maximum(_standardise(x[test], mean, scale) @ weights + intercept, 0.0)
            total += float(np.abs(predicted - y[test]).sum())
        errors.append(total)
    return ALPHAS[int(np.argmin(errors))]
