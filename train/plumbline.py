"""The classical floor (issue 23 item 2): a plumb-line miscalibration detector, line curvature plus a ridge fit.

A rectification with the wrong calibration leaves a smooth non-affine warp in the image, which bends the scene's
straight edges. line_features measures that bend: long segments (OpenCV's LSD on a copy at most DETECT_WIDTH
wide), then the edge's sub-pixel position across each one at SAMPLES points (the peak of the directional
derivative along its normal, on the full-resolution image), and from those offsets

- each segment's bulge: the quadratic term of its offsets, the middle's distance from the chord, signed positive
  away from the image centre (a radial error bows lines away from or towards the centre, more the further out);
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

from appdgen.errors import AppdgenError

#: LSD runs on a copy at most this wide (INTER_AREA): long edges survive, texture fragments less (73 of 899 segments
#: were long at full 1392×512), and it is faster; the offsets are still measured on the full-resolution gradient.
DETECT_WIDTH = 720
#: A segment counts when at least this long (fraction of the image diagonal, and pixels).
MIN_LENGTH = 0.035
MIN_LENGTH_PX = 10.0
MAX_SEGMENTS = 240  # the longest ones; more add little and cost time
SAMPLES = 31  # positions along a segment, its ends left out: a corner's other edge pulls the peak towards itself
END_MARGIN = 0.1  # of the length, and at least END_MARGIN_PX
END_MARGIN_PX = 3.0
REACH_PX = 3.0  # how far across a segment the edge is looked for (pixels of the image), both sides
STEP_PX = 0.5
#: How the gradient is read between pixels. Against bilinear, out-of-fold Spearman ρ on bend at 1392×512 over three
#: sets of fresh pairs (seeds 0, 1, 2; 100, 60, 120 pairs): 0.47 / 0.61 / 0.65 against 0.55 / 0.40 / 0.57; at
#: 348×128 a wash (0.08 / 0.28 / 0.25 against 0.11 / 0.21 / 0.25).
PROFILE_INTERP = cv2.INTER_CUBIC
SOBEL_SIZE = 3
MIN_VALID = 8  # samples with a clear edge a segment needs
SMALLEST_SIDE = 16  # pixels: a smaller image has no measurable lines; its features are zeros
#: Diagonals: how far the principal point may sit from the image centre. Using the reference crop's own principal
#: point instead (0.022 diagonals above the centre for KITTI) ranked bend no better (out-of-fold ρ 0.64/0.52/0.25
#: against 0.65/0.61/0.25 on three sets of pairs), so the image centre stays: it needs no calibration.
CENTRE_SPREAD = 0.05
CAUCHY = 2.0  # the reweighting's scale, in standard errors of a segment's own k
ROUNDS = 3
NOISE_FLOOR = 0.05  # pixels: no edge position is trusted closer than this (a clean synthetic edge fits to ~0)
GRID = (48, 18)  # columns, rows of the grid the radial field's non-affine part is averaged on

#: The vector's entries: the mean length of the non-affine part of the radial field the lines' bulges point to, in %
#: of the diagonal (an estimate of bend_pct), its signed coefficient k, and log(1 + Σ (lever / noise)²): how
#: firmly the scene's lines pin k down. Richer vectors (segment counts, edge noise, bulge and curvature statistics
#: binned by distance from the centre, a decentred plumb-line field, the vanishing point) ranked bend worse after
#: the same ridge fit on the same frames (issue 23's notes), and the linear floor must work from a few dozen images.
FEATURE_NAMES: tuple[str, ...] = ("radial_bend", "radial_k1", "radial_support")
FEATURES: int = len(FEATURE_NAMES)
FORMAT = "appdgen.plumbline/1"


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


def segments(grey: np.ndarray) -> np.ndarray:
    """Long line segments (x0, y0, x1, y1) in pixels of the image, longest first (S×4 float64)."""
    height, width = grey.shape
    factor = min(1.0, DETECT_WIDTH / width)
    small = grey if factor == 1.0 else cv2.resize(grey, (round(width * factor), round(height * factor)),
                                                  interpolation=cv2.INTER_AREA)
    found = cv2.createLineSegmentDetector(cv2.LSD_REFINE_NONE).detect(small)[0]
    if found is None or len(found) == 0:
        return np.zeros((0, 4))
    lines = found.reshape(-1, 4).astype(np.float64)
    if factor != 1.0:  # pixel centres at integers: an edge at −0.5 stays there
        lines = (lines + 0.5) * np.array([width / small.shape[1], height / small.shape[0]] * 2) - 0.5
    length = np.hypot(lines[:, 2] - lines[:, 0], lines[:, 3] - lines[:, 1])
    keep = length >= max(MIN_LENGTH * math.hypot(width, height), MIN_LENGTH_PX)
    order = np.argsort(-length[keep], kind="stable")[:MAX_SEGMENTS]
    return lines[keep][order]


@dataclass(frozen=True)
class _Offsets:
    """Edge positions across S segments at J samples: offsets along the outward normal (pixels), which samples had a
    clear edge, the sample points (pixels) and where they lie along the sampled span."""

    offset: np.ndarray  # S×J
    valid: np.ndarray  # S×J bool
    points: np.ndarray  # S×J×2
    normal: np.ndarray  # S×2, pointing away from the centre
    t: np.ndarray  # J, 0…1 over the sampled span (the segment less its ends)


def edge_offsets(grey: np.ndarray, lines: np.ndarray, centre: np.ndarray) -> _Offsets:
    """Sub-pixel edge positions across each segment: the peak of the derivative along its normal (pixels), the
    normal pointing away from `centre` (pixels)."""
    a, b = lines[:, :2], lines[:, 2:]
    direction = (b - a) / np.linalg.norm(b - a, axis=1, keepdims=True)
    normal = np.column_stack([-direction[:, 1], direction[:, 0]])
    outward = np.einsum("sk,sk->s", normal, (a + b) / 2 - centre)
    normal = np.where((outward < 0)[:, None], -normal, normal)
    t = np.linspace(0.0, 1.0, SAMPLES)
    margin = np.maximum(END_MARGIN, END_MARGIN_PX / np.linalg.norm(b - a, axis=1))
    along = margin[:, None] + (1 - 2 * margin[:, None]) * t[None, :]
    points = a[:, None, :] + along[:, :, None] * (b - a)[:, None, :]
    across = np.arange(-REACH_PX, REACH_PX + STEP_PX / 2, STEP_PX)
    taps = points[:, :, None, :] + across[None, None, :, None] * normal[:, None, None, :]  # S×J×K×2
    gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=SOBEL_SIZE)
    gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=SOBEL_SIZE)
    shape = taps.shape[:3]
    map_x = taps[..., 0].reshape(-1, len(across)).astype(np.float32)
    map_y = taps[..., 1].reshape(-1, len(across)).astype(np.float32)
    sx = cv2.remap(gx, map_x, map_y, PROFILE_INTERP, borderMode=cv2.BORDER_REPLICATE).reshape(shape)
    sy = cv2.remap(gy, map_x, map_y, PROFILE_INTERP, borderMode=cv2.BORDER_REPLICATE).reshape(shape)
    profile = sx * normal[:, None, None, 0] + sy * normal[:, None, None, 1]  # derivative along the normal
    middle = len(across) // 2
    polarity = np.sign(profile[:, :, middle - 2:middle + 3].sum(axis=(1, 2)))  # the edge's own sign, not its twin's
    profile = profile * polarity[:, None, None]
    peak = np.argmax(profile, axis=2)
    inner = np.clip(peak, 1, len(across) - 2)
    left, top, right = (np.take_along_axis(profile, (inner + d)[..., None], axis=2)[..., 0] for d in (-1, 0, 1))
    curve = left - 2 * top + right
    shift = np.where(curve < 0, 0.5 * (left - right) / np.where(curve < 0, curve, -1.0), 0.0)
    offset = across[inner] + np.clip(shift, -0.5, 0.5) * STEP_PX
    strength = np.median(top, axis=1, keepdims=True)
    valid = (peak == inner) & (curve < 0) & (top > 0.3 * strength) & (top > 4.0) & (polarity[:, None] != 0)
    return _Offsets(offset, valid, points + offset[..., None] * normal[:, None, :], normal, t)


def _quadratic(offsets: _Offsets) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per segment: the bulge (middle minus chord of the fitted parabola, pixels, outward positive), the residual
    RMS (pixels) and which samples are kept (clear edges, outliers of the parabola dropped once)."""
    s = 2 * offsets.t - 1
    design = np.column_stack([np.ones_like(s), s, s * s])  # J×3
    valid = offsets.valid.copy()
    for _ in range(2):
        w = valid.astype(np.float64)
        normal = np.einsum("sj,jk,jl->skl", w, design, design) + 1e-9 * np.eye(3)
        coef = np.linalg.solve(normal, np.einsum("sj,jk,sj->sk", w, design, offsets.offset)[..., None])[..., 0]
        residual = offsets.offset - coef @ design.T
        count = w.sum(axis=1)
        rms = np.sqrt((w * residual ** 2).sum(axis=1) / np.maximum(count - 3, 1))
        valid &= np.abs(residual) <= np.maximum(3 * rms, 0.25)[:, None]
    return -coef[:, 2], rms, valid & (valid.sum(axis=1) >= MIN_VALID)[:, None]


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
    x, y = (a.ravel() for a in np.meshgrid(np.linspace(-half_w, half_w, GRID[0]), np.linspace(-half_h, half_h, GRID[1])))
    rho2 = x * x + y * y
    design = np.column_stack([np.ones_like(x), x, y])
    rest = [w - design @ np.linalg.lstsq(design, w, rcond=None)[0] for w in (x * rho2, y * rho2)]
    return float(np.hypot(*rest).mean())


def line_features(image: np.ndarray) -> np.ndarray:
    """The plumb-line feature vector of one rectified image (FEATURES float64, lengths in units of its diagonal;
    FEATURE_NAMES says which is which); zeros where the image shows no long lines."""
    grey = _grey(image)
    features = np.zeros(FEATURES)
    height, width = grey.shape
    if min(height, width) < SMALLEST_SIDE:
        return features
    diagonal = math.hypot(width, height)
    centre = np.array([(width - 1) / 2, (height - 1) / 2])
    lines = segments(grey)
    if len(lines) == 0:
        return features
    offsets = edge_offsets(grey.astype(np.float32), lines, centre)
    bulge, rms, kept = _quadratic(offsets)
    stands = kept.any(axis=1)
    if not stands.any():
        return features
    length = np.hypot(lines[:, 2] - lines[:, 0], lines[:, 3] - lines[:, 1])
    distance = np.abs(np.einsum("sk,sk->s", offsets.normal, (lines[:, :2] + lines[:, 2:]) / 2 - centre))
    half = length * (1 - 2 * np.maximum(END_MARGIN, END_MARGIN_PX / length)) / 2  # of the sampled span
    lever = distance * half ** 2 / diagonal ** 2  # pixels of bulge per unit k
    k = radial_k1(bulge[stands], rms[stands], lever[stands], distance[stands] / diagonal)
    support = float(np.sum(lever[stands] ** 2 / (rms[stands] ** 2 + NOISE_FLOOR ** 2)))
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
            raise AppdgenError(f"not a plumb-line detector (format {data.get('format') if isinstance(data, dict) else None!r}, expected {FORMAT})")
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
