"""Procedural tiling gain maps (float32 around 1.0): asphalt, paving, bricks, panels, planks, plaster."""
from __future__ import annotations

import functools
import zlib

import cv2
import numpy as np

#: Blur (texels) of each mip level; the last level is the texture's mean, for very distant surfaces.
MIP_SIGMAS = (0.0, 1.0, 2.0, 4.0, 8.0)
POOL = 4  # variants of each kind: frames pick among them, so texture synthesis is paid once per process


def smooth_noise(rng: np.random.Generator, shape: tuple[int, int], cells: int) -> np.ndarray:
    """Zero-mean, unit-std noise that tiles seamlessly, with about `cells` blobs across each side."""
    coarse = rng.standard_normal((cells, cells), dtype=np.float32)
    h, w = shape
    # Interpolating with the opposite edges as neighbours (2 cells of wrap padding) makes the result tile seamlessly.
    padded = cv2.copyMakeBorder(coarse, 2, 2, 2, 2, cv2.BORDER_WRAP)
    cw, ch = w / cells, h / cells
    big = cv2.resize(padded, (round((cells + 4) * cw), round((cells + 4) * ch)), interpolation=cv2.INTER_CUBIC)
    big = big[round(2 * ch) : round(2 * ch) + h, round(2 * cw) : round(2 * cw) + w]
    return (big - big.mean()) / (big.std() + 1e-6)


def grain(rng: np.random.Generator, shape: tuple[int, int], fine: float, coarse: float) -> np.ndarray:
    """1 + white noise (std `fine`) + blotches (std `coarse`): the base of every surface."""
    noise = fine * rng.standard_normal(shape, dtype=np.float32)
    return 1.0 + noise + coarse * smooth_noise(rng, shape, 4)


def asphalt(rng: np.random.Generator) -> np.ndarray:
    """Asphalt at 20 texels/m: fine grain, darker patches."""
    return grain(rng, (256, 256), 0.08, 0.06)


def courses(
    rng: np.random.Generator, unit: tuple[int, int], counts: tuple[int, int], joint: int, stagger: bool, spread: float
) -> np.ndarray:
    """Bricks/tiles/blocks of `unit` (w, h) texels in `counts` (columns, rows), dark joints, per-unit shade."""
    (uw, uh), (nx, ny) = unit, counts
    shades = 1.0 + spread * rng.standard_normal((ny, nx), dtype=np.float32)
    cols = np.arange(nx * uw)
    rows = np.arange(ny * uh) // uh
    offset = np.where(rows % 2 == 1, uw // 2, 0) if stagger else np.zeros_like(rows)
    col_index = (cols[None, :] + offset[:, None]) // uw % nx  # wraps: the brick across the seam is one brick
    gain = shades[rows[:, None], col_index]
    in_joint = ((cols[None, :] + offset[:, None]) % uw < joint) | ((np.arange(ny * uh) % uh) < joint)[:, None]
    gain = np.where(in_joint, 0.72, gain)
    return gain * grain(rng, gain.shape, 0.04, 0.03)


def bricks(rng: np.random.Generator) -> np.ndarray:
    """Running-bond brick at 40 texels/m: 25 × 10 cm bricks, 2.5 cm joints."""
    return courses(rng, (10, 4), (12, 32), 1, True, 0.09)


def blocks(rng: np.random.Generator) -> np.ndarray:
    """Stone blocks / large tiles at 40 texels/m."""
    w, h = int(rng.integers(16, 32)), int(rng.integers(10, 20))
    return courses(rng, (w, h), (256 // w, 256 // h), 1, bool(rng.random() < 0.6), 0.05)


def paving(rng: np.random.Generator) -> np.ndarray:
    """Square pavement slabs, 30–60 cm, at 40 texels/m."""
    side = int(rng.integers(12, 24))
    return courses(rng, (side, side), (256 // side, 256 // side), 1, bool(rng.random() < 0.3), 0.04)


def panels(rng: np.random.Generator) -> np.ndarray:
    """Concrete or metal panels 1.2–3 m wide with thin seams, at 20 texels/m."""
    w, h = int(rng.integers(24, 60)), int(rng.integers(20, 60))
    return courses(rng, (w, h), (max(256 // w, 1), max(256 // h, 1)), 1, False, 0.04)


def planks(rng: np.random.Generator) -> np.ndarray:
    """Horizontal siding boards 15–30 cm high, at 40 texels/m."""
    h = int(rng.integers(6, 12))
    return courses(rng, (256, h), (1, 256 // h), 1, False, 0.03)


def plaster(rng: np.random.Generator) -> np.ndarray:
    """Rendered wall: faint blotches and grain, at 20 texels/m."""
    return grain(rng, (128, 128), 0.03, 0.05)


#: Texture kinds: maker and texels per metre.
KINDS = {
    "bricks": (bricks, 40.0), "blocks": (blocks, 40.0), "panels": (panels, 20.0), "planks": (planks, 40.0),
    "plaster": (plaster, 20.0), "asphalt": (asphalt, 20.0), "paving": (paving, 40.0), "grass": (plaster, 10.0),
}


@functools.lru_cache(maxsize=None)
def pooled(kind: str, variant: int) -> tuple[np.ndarray, ...]:
    """Mip levels of one fixed variant of a texture kind, seeded by (kind, variant) alone: deterministic, cached."""
    rng = np.random.default_rng(np.random.SeedSequence([zlib.crc32(kind.encode()), variant]))
    return mip_levels(KINDS[kind][0](rng))


def mip_levels(gain: np.ndarray) -> tuple[np.ndarray, ...]:
    """Pre-blurred copies of a tiling gain map, one per MIP_SIGMAS entry (blurred with wrap-around)."""
    gain = gain.astype(np.float32)
    h, w = gain.shape
    levels = [gain]
    for sigma in MIP_SIGMAS[1:-1]:
        # GaussianBlur has no wrap-around border: pad with the opposite edges, blur, cut the padding off.
        pad = min(int(3 * sigma) + 1, h, w)
        padded = cv2.copyMakeBorder(gain, pad, pad, pad, pad, cv2.BORDER_WRAP)
        levels.append(np.ascontiguousarray(cv2.GaussianBlur(padded, (0, 0), sigma)[pad : pad + h, pad : pad + w]))
    levels.append(np.full((1, 1), gain.mean(), np.float32))  # a 1×1 tile wraps to a constant
    return tuple(levels)
