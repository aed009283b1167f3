"""A third-order field lookup tried in place of the product's (docs/studies/real-sets.md, "The field lookup …"):
Catmull-Rom (a = −0.5) on the field model's grid, one ghost node per side on the quadratic through the nearest
three, a point off the grid read at its nearest edge. It reads a belief's exact field between nodes ~15 × closer
than the product's first-order bicubic, yet makes the detector read more field under a true calibration (real and
synthetic frames), so it is kept here as an experiment, not in appdgen.detect.

    python -m studies.lookup realsets --beliefs 16 --out runs/realsets-cr
    python -m studies.lookup bendfield --axes unseen --lenses "" --no-sequential --sequences 32 --out runs/bf-cr

runs the named study (its own arguments after the name) with this lookup swapped into appdgen.detect.
"""
from __future__ import annotations

import importlib
import sys
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

import appdgen.detect.baseline as baseline_module
import appdgen.detect.model as model_module

STUDIES = ("realsets", "bendfield")


def catmull_rom_lookup(grid_u: np.ndarray, grid_v: np.ndarray, fields: np.ndarray, u: np.ndarray, v: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Fields (M, gy, gx, 2) on a regular grid, Catmull-Rom at points (u, v): first (N, 2) and the rest (N, M-1, 2),
    output px (the product's field_lookup's contract)."""
    m, gy, gx, _ = fields.shape
    stack = padded_quadratic(padded_quadratic(fields.transpose(1, 2, 0, 3).reshape(gy, gx, 2 * m), 0), 1)
    iu, wu = cubic_taps((np.asarray(u, float).ravel() - grid_u[0]) / (grid_u[1] - grid_u[0]), gx)
    iv, wv = cubic_taps((np.asarray(v, float).ravel() - grid_v[0]) / (grid_v[1] - grid_v[0]), gy)
    cols = iu[:, None] + np.arange(4)
    out = np.zeros((iu.size, 2 * m))
    for a in range(4):
        out += wv[:, a, None] * np.einsum("nb,nbc->nc", wu, stack[(iv + a)[:, None], cols])
    out = out.reshape(-1, m, 2)
    return out[:, 0], out[:, 1:]


def padded_quadratic(values: np.ndarray, axis: int) -> np.ndarray:
    """Values with one ghost node added at each end of `axis`, on the quadratic through the nearest three nodes."""
    v = np.moveaxis(values, axis, 0)
    first = 3.0 * v[0] - 3.0 * v[1] + v[2]
    last = 3.0 * v[-1] - 3.0 * v[-2] + v[-3]
    return np.moveaxis(np.concatenate([first[None], v, last[None]]), 0, axis)


def cubic_taps(pos: np.ndarray, nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """First padded node index (N,) and Catmull-Rom weights (N, 4) at grid positions `pos` (node units), a position
    off the grid read at its nearest edge."""
    # A cubic extrapolated off the grid runs away; points mapped from another rectification (a baseline's, a
    # simulated belief's) do land there.
    pos = np.clip(pos, 0.0, nodes - 1.0)
    cell = np.minimum(np.floor(pos), nodes - 2).astype(np.intp)
    t = pos - cell
    x = np.abs(np.stack([t + 1.0, t, 1.0 - t, 2.0 - t], -1))
    near = (1.5 * x - 2.5) * x * x + 1.0
    far = ((-0.5 * x + 2.5) * x - 4.0) * x + 2.0
    return cell, np.where(x <= 1.0, near, far)


@contextmanager
def swapped() -> Iterator[None]:
    """appdgen.detect reading its fields (the model's and a baseline's) with catmull_rom_lookup, inside the block."""
    before = model_module.field_lookup
    model_module.field_lookup = baseline_module.field_lookup = catmull_rom_lookup
    try:
        yield
    finally:
        model_module.field_lookup = baseline_module.field_lookup = before


def main(argv: list[str] | None = None) -> None:
    """Run studies.<name> with the swapped lookup: `python -m studies.lookup NAME [ITS ARGUMENTS]`."""
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] not in STUDIES:
        print(f"usage: python -m studies.lookup {{{','.join(STUDIES)}}} [the study's arguments]", file=sys.stderr)
        sys.exit(2)
    study = importlib.import_module(f"studies.{argv[0]}")
    with swapped():  # bendfield's --jobs workers are forked (Linux), so they inherit the swap
        study.main(argv[1:])


if __name__ == "__main__":
    main()
