"""The lens-model layer: one module per model, each the same few pure functions of (points, coefficients).

A model module defines

* ``NAME``: the model's name as appdgen spells it (``radtan``, ``rational``, ``kb4``, ``ds``, ``eucm``);
* ``PARAMS``: its coefficient names, in the order files and ``coeffs`` tuples use;
* ``project(x, y, coeffs)``: undistorted normalized coordinates (x = X/Z, y = Y/Z) → distorted normalized
  coordinates (m_x, m_y), so that the raw pixel is (fx·m_x + cx, fy·m_y + cy); written against the Python array
  API (numerics.namespace), so numpy arrays and torch tensors run the same equations, and coefficients may be
  arrays broadcasting against x, y (one calibration per batch row: appdgen.geometry.maps.raw_positions_batch);
* ``jacobian(x, y, coeffs)``: (∂m_x/∂x, ∂m_x/∂y, ∂m_y/∂x, ∂m_y/∂y) of ``project``;
* ``fold_radius(coeffs)``: the undistorted normalized radius below which ``project`` is one-to-one (inf when
  none is found), the model's valid domain;
* ``maps(K, coeffs, new_K, size)``: float32 rectification maps (raw pixel positions per output pixel);
* ``unproject_rays(mx, my, coeffs)``: distorted normalized coordinates → unit rays (X, Y, Z), which may point
  past 90° for fisheye models; NaN where the model has no valid preimage;
* ``plane_guess(mx, my, coeffs)``: a starting point in the undistorted plane for Newton's inverse (NaN where the
  ray is at or past 90°, so not in the plane);
* ``validate(coeffs)``: AppdgenError when the coefficients are not a camera of this model;
* optionally ``project_axis(t, fixed, rows, coeffs)``: (m_x, ∂m_x/∂x) at (x, y) = (t, fixed) where the boolean
  array ``rows`` is set, else (m_y, ∂m_y/∂y) at (fixed, t): the crop's 1-D boundary solve, which otherwise builds
  it from ``project`` and ``jacobian`` (radtan and rational supply it: half the work, the crop's hot loop).

The undistorted normalized plane only holds rays under 90° off-axis; a model that sees further is still described
there, and its ``fold_radius`` is inf when it is one-to-one up to 90°. Helpers shared by the models live in
``appdgen.lens.numerics``.

Modules take plain tuples of floats and never import the calibration type (which imports this registry).
"""
from __future__ import annotations

import functools
import importlib
from types import ModuleType

from appdgen.errors import AppdgenError

#: Supported model names → their module (under appdgen.lens). Adding a model = one module + one entry here.
MODELS: dict[str, str] = {"radtan": "radtan", "rational": "rational", "kb4": "kb4", "ds": "ds", "eucm": "eucm"}
#: Models met in calibration files that appdgen refuses, with why (readers pass these names to get()).
UNSUPPORTED: dict[str, str] = {
    "tilted": "OpenCV's tilted-sensor model (14 coefficients, taux/tauy) is not a pinhole behind the lens",
    "omni": "Kalibr's omni (Mei's unified model with radial-tangential distortion) is not implemented",
    "fov": "the FOV (Devernay–Faugeras arctan) distortion model is not implemented",
}


def get(name: str) -> ModuleType:
    """The module implementing lens model `name`; AppdgenError naming the supported ones otherwise."""
    if name not in MODELS:
        why = f"{UNSUPPORTED[name]}; " if name in UNSUPPORTED else ""
        raise AppdgenError(f"lens model {name!r} is not supported: {why}supported: {', '.join(MODELS)}")
    return _module(name)


@functools.cache
def _module(name: str) -> ModuleType:
    """The imported module of a supported model (cached: the crop asks ~10 times per evaluation)."""
    return importlib.import_module(f"appdgen.lens.{MODELS[name]}")


def params(name: str) -> tuple[str, ...]:
    """The coefficient names of lens model `name`, in order."""
    return get(name).PARAMS
