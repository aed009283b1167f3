"""The believed camera's field model: a library of hypotheses for the TRUE camera around the belief, each with its
bend as the belief-rectified image shows it, compressed to a PCA basis; cached on disk.

The prior is the sampling one read the way a miscalibration arises: the belief is a sampler draw around the truth
(Θb = Θt + δ, as `appdgen build` perturbs its reference), so hypothesis i is Θt = Θb − δi with δi the offset of
Sampler(belief).draw(LIBRARY_SEED, i) (the ranges are asymmetric, focal −5 %…+20 %: taking the draw itself as the
truth would put the prior's mass on the wrong side). For a hypothesis Θt the image rectified with the belief Θb
shows at output pixel p the ray of the true-rectification pixel W(p) = K̂t·undistort_t(M̂b(p)); its non-affine rest
in belief output pixels (geometry.bend.output_rest) is the field f with p_i + f(p_i) collinear along every straight
scene edge. The field is sampled on a grid spanning the whole raw-size output image, and every draw keeps its
labels: APPD and bend (% of the raw diagonal, as a build labels the belief-rectified sample of a reference Θt) and
its parameter offsets (true − belief, parameter units).
"""
from __future__ import annotations

import functools
import hashlib
import io
import json
import os
import time
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from appdgen.calib.calibration import Calibration
from appdgen.errors import AppdgenError
from appdgen.geometry.appd import px_to_pct
from appdgen.geometry.bend import output_rest, warp_field
from appdgen.geometry.crop import Crop, valid_region
from appdgen.sampling.ranges import default_ranges
from appdgen.sampling.reach import UnreachableError
from appdgen.sampling.sampler import Sampler
from appdgen.util.atomic import write_file
from appdgen.version import __version__

#: Bump when the model's content or meaning changes: older cache files are then ignored.
MODEL_VERSION = 4
LIBRARY_SEED = 4242  # library draw i is Sampler(belief).draw(LIBRARY_SEED, i)
LIBRARY_DRAWS = 1000  # draws of a radtan camera of KITTI's size or smaller: ~12 s on one idle core
#: Draws per lens model at KITTI's raw size or smaller: each lens's crop search and label cost differ, so that a
#: model is ready in about 20 s on one core (docs/studies/bend-field-detector.md). Larger cameras get
#: proportionally fewer, never fewer than LEAST_DRAWS. The size depends on the belief only: the same belief always
#: reads the same.
LENS_DRAWS = {"radtan": LIBRARY_DRAWS, "rational": LIBRARY_DRAWS, "kb4": 200, "ds": 300, "eucm": 300}
REFERENCE_PIXELS = 1392 * 512
LEAST_DRAWS = 100
COMPONENTS = 12  # PCA components of the field
GRID_SPACING = 32.0  # output px between field grid nodes (corners included)
#: Grid points across the output for the labels (geometry.bend's grid): APPD to ~1e-4 % of the full-grid label.
LABEL_COLUMNS = 48


@dataclass(frozen=True)
class FieldModel:
    """A belief's library and field basis (arrays; grid in belief output px)."""

    grid_u: np.ndarray  # (gx,) node columns, output px
    grid_v: np.ndarray  # (gy,) node rows, output px
    mean: np.ndarray  # (gy, gx, 2) mean field, output px
    basis: np.ndarray  # (K, gy, gx, 2) orthonormal components (as flattened vectors)
    coefs: np.ndarray  # (n, K) library draws' coefficients
    appd: np.ndarray  # (n,) APPD % of the raw diagonal
    bend: np.ndarray  # (n,) bend % of the raw diagonal
    offsets: np.ndarray  # (n, P) true − belief, parameter units
    names: tuple[str, ...]  # parameter names of offsets' columns
    seconds: float  # time the library and basis took to build

    @property
    def var(self) -> np.ndarray:
        """(K,) prior variance of each coefficient over the library."""
        return self.coefs.var(0) + 1e-12

    def field_at(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean field (N, 2) and components (N, K, 2) at output pixels (u, v): Catmull-Rom on the grid, output px."""
        return field_lookup(self.grid_u, self.grid_v, np.concatenate([self.mean[None], self.basis]), u, v)

    def field_of(self, c: np.ndarray) -> np.ndarray:
        """(gy, gx, 2) field mean + Σ c_k B_k on the grid, output px."""
        return self.mean + np.tensordot(c, self.basis, axes=1)

    @property
    def targets(self) -> np.ndarray:
        """(n, 2 + P) the library's labels: APPD, bend (% of the raw diagonal) and offsets (parameter units)."""
        return np.column_stack([self.appd, self.bend, self.offsets])


def field_lookup(grid_u: np.ndarray, grid_v: np.ndarray, fields: np.ndarray, u: np.ndarray, v: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Fields (M, gy, gx, 2) on a regular grid, Catmull-Rom at points (u, v): first (N, 2) and the rest (N, M-1, 2),
    output px; a point off the grid reads its nearest edge."""
    # Third order on purpose: OpenCV's INTER_CUBIC (a = -0.75) misplaces a belief's rest between 32 px nodes by
    # ~0.15 px on edge points, more than a segment's bend, and the solve then read large fields far too small
    # (docs/studies/real-sets.md, 2026-12-07).
    m, gy, gx, _ = fields.shape
    stack = _ghost_nodes(_ghost_nodes(fields.transpose(1, 2, 0, 3).reshape(gy, gx, 2 * m), 0), 1)
    iu, wu = _cubic_taps((np.asarray(u, float).ravel() - grid_u[0]) / (grid_u[1] - grid_u[0]), gx)
    iv, wv = _cubic_taps((np.asarray(v, float).ravel() - grid_v[0]) / (grid_v[1] - grid_v[0]), gy)
    cols = iu[:, None] + np.arange(4)
    out = np.zeros((iu.size, 2 * m))
    for a in range(4):
        out += wv[:, a, None] * np.einsum("nb,nbc->nc", wu, stack[(iv + a)[:, None], cols])
    out = out.reshape(-1, m, 2)
    return out[:, 0], out[:, 1:]


def _ghost_nodes(values: np.ndarray, axis: int) -> np.ndarray:
    """Values with one node added at each end of `axis`, on the quadratic through the nearest three."""
    v = np.moveaxis(values, axis, 0)
    first = 3.0 * v[0] - 3.0 * v[1] + v[2]
    last = 3.0 * v[-1] - 3.0 * v[-2] + v[-3]
    return np.moveaxis(np.concatenate([first[None], v, last[None]]), 0, axis)


def _cubic_taps(pos: np.ndarray, nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """First node index (N,) of the ghost-padded grid and Catmull-Rom weights (N, 4) at positions `pos` (node units),
    clipped to the grid."""
    # A cubic extrapolated off the grid runs away; points mapped from another rectification (a baseline's, a
    # simulated belief's) do land there.
    pos = np.clip(pos, 0.0, nodes - 1.0)
    cell = np.minimum(np.floor(pos), nodes - 2).astype(np.intp)
    t = pos - cell
    x = np.abs(np.stack([t + 1.0, t, 1.0 - t, 2.0 - t], -1))
    near = (1.5 * x - 2.5) * x * x + 1.0
    far = ((-0.5 * x + 2.5) * x - 4.0) * x + 2.0
    return cell, np.where(x <= 1.0, near, far)


def field_grid(calib: Calibration, spacing: float = GRID_SPACING) -> tuple[np.ndarray, np.ndarray]:
    """Node columns and rows spanning a raw-size output image, corners included (output px)."""
    w, h = calib.size
    return (np.linspace(0.0, w - 1.0, int(round((w - 1) / spacing)) + 1),
            np.linspace(0.0, h - 1.0, int(round((h - 1) / spacing)) + 1))


@functools.lru_cache(maxsize=16)
def belief_crop(belief: Calibration, max_fov: float | None) -> Crop:
    """The crop `appdgen build` gives the reference under --max-fov: the one the detector rectifies with (cached:
    a baseline's reading maps every frame's points through the REF's and the belief's crops, a search each)."""
    return valid_region(belief, max_fov=max_fov)


def default_draws(belief: Calibration) -> int:
    """The library size of a belief: LENS_DRAWS of its lens model, fewer for a raw size above KITTI's."""
    w, h = belief.size
    if belief.model not in LENS_DRAWS:
        raise AppdgenError(f"appdgen detect has no field model for the {belief.model!r} lens model "
                           f"(it reads {', '.join(sorted(LENS_DRAWS))})")
    most = LENS_DRAWS[belief.model]
    return max(LEAST_DRAWS, min(most, round(most * REFERENCE_PIXELS / (w * h))))


def build_model(belief: Calibration, max_fov: float | None = None, draws: int | None = None,
                components: int = COMPONENTS, progress: Callable[[str], None] | None = None) -> FieldModel:
    """Draw the library around the belief (`draws`, default_draws(belief) when None), label it and fit the field
    basis."""
    draws = default_draws(belief) if draws is None else draws
    start = time.perf_counter()
    sampler = Sampler(belief, max_fov=max_fov)
    crop_b = belief_crop(belief, max_fov)
    grid_u, grid_v = field_grid(belief)
    uu, vv = np.meshgrid(grid_u, grid_v)
    base = np.array(list(belief.params().values()))
    fields, appd, bend, offsets = [], [], [], []
    for i in range(draws):
        try:
            d = sampler.draw(LIBRARY_SEED, i)
        except UnreachableError:  # a target at the very top of what the belief's ranges reach: not a hypothesis
            continue
        if progress is not None and (i + 1) % 250 == 0:
            progress(f"field model: {i + 1}/{draws} draws")
        offset = base - np.array(list(d.calib.params().values()))  # the belief is the draw around the truth
        if d.is_reference:
            fields.append(np.zeros(uu.shape + (2,)))
            appd.append(0.0)
            bend.append(0.0)
            offsets.append(offset)
            continue
        try:
            true = belief.replace(**dict(zip(belief.param_names, (base + offset).tolist(), strict=True)))
            crop_t = valid_region(true, max_fov=max_fov)
            field = output_rest(true, crop_t, belief, crop_b, uu, vv).reshape(uu.shape + (2,))
            wf = warp_field(true, crop_t, belief, crop_b, columns=LABEL_COLUMNS)
        except AppdgenError:  # the mirrored camera cannot be rectified: not a hypothesis
            continue
        fields.append(field)
        appd.append(px_to_pct(wf.appd_px, belief))
        bend.append(px_to_pct(wf.bend_px, belief))
        offsets.append(offset)
    flat = np.array(fields).reshape(len(fields), -1)
    mean = flat.mean(0)
    basis = principal_axes(flat - mean, components)
    shape = uu.shape + (2,)
    return FieldModel(grid_u, grid_v, mean.reshape(shape), basis.reshape((components,) + shape),
                      (flat - mean) @ basis.T, np.array(appd), np.array(bend), np.array(offsets), belief.param_names,
                      time.perf_counter() - start)


def principal_axes(centred: np.ndarray, components: int) -> np.ndarray:
    """(components, D) orthonormal leading principal axes of n centred rows, through the n×n Gram matrix."""
    evals, evecs = np.linalg.eigh(centred @ centred.T)
    top = np.argsort(evals)[::-1][:components]
    axes = (centred.T @ evecs[:, top]) / np.sqrt(np.maximum(evals[top], 1e-300))
    return axes.T


def model_key(belief: Calibration, max_fov: float | None, draws: int | None = None) -> str:
    """Cache key of a belief's model: everything that decides it (the belief, max_fov, the sampler's ranges and
    APPD range, the library's seed and size, the basis, grid and label settings, the model and package versions)."""
    sampler = Sampler(belief, max_fov=max_fov)
    ranges = {name: [r.low, r.high, r.relative] for name, r in default_ranges(belief).items()}
    fields = {"calib": belief.to_dict(), "max_fov": max_fov, "version": MODEL_VERSION, "package": __version__,
              "draws": default_draws(belief) if draws is None else draws, "components": COMPONENTS,
              "spacing": GRID_SPACING, "seed": LIBRARY_SEED, "label_columns": LABEL_COLUMNS, "ranges": ranges,
              "appd_max": sampler.appd_max}
    text = json.dumps(fields, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def default_cache_dir() -> Path:
    """$APPDGEN_CACHE/detect, else ~/.cache/appdgen/detect."""
    root = os.environ.get("APPDGEN_CACHE")
    return Path(root) / "detect" if root else Path.home() / ".cache" / "appdgen" / "detect"


_ARRAYS = ("grid_u", "grid_v", "mean", "basis", "coefs", "appd", "bend", "offsets")


def load_model(path: Path) -> FieldModel | None:
    """A cached model, or None when absent or unreadable (it is rebuilt then)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in _ARRAYS}
            names = tuple(str(n) for n in z["names"])
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile):  # absent, truncated or foreign
        return None
    return FieldModel(**arrays, names=names, seconds=0.0)


def save_model(model: FieldModel, path: Path) -> bool:
    """Write a model to the cache (atomically); False when the cache cannot be written (not an error)."""
    buffer = io.BytesIO()
    np.savez(buffer, **{k: getattr(model, k) for k in _ARRAYS}, names=np.array(model.names))
    try:
        write_file(path, buffer.getvalue())
    except AppdgenError:  # an unwritable cache only costs the next run the build
        return False
    return True


def cached_model(belief: Calibration, max_fov: float | None, cache_dir: Path | None,
                 progress: Callable[[str], None] | None = None, draws: int | None = None
                 ) -> tuple[FieldModel, bool]:
    """The belief's model from the cache, else built (and cached when the folder is writable); (model, was_cached)."""
    key = model_key(belief, max_fov, draws)
    path = (cache_dir if cache_dir is not None else default_cache_dir()) / f"field-{key}.npz"
    model = load_model(path)
    if model is not None:
        return model, True
    model = build_model(belief, max_fov, draws, progress=progress)
    save_model(model, path)
    return model, False
