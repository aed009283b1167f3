"""The lens-model layer: one module per model, each the same few pure functions of (points, coefficients).

A model module defines

* ``NAME``: the model's name as appdgen spells it (``radtan``, ``rational``, ``kb4``, ``ds``, ``eucm``);
* ``PARAMS``: its coefficient names, in the order files and ``coeffs`` tuples use;
* ``project(x, y, coeffs)``: undistorted normalized coordinates (x = X/Z, y = Y/Z) → distorted normalized
  coordinates (m_x, m_y), so that the raw pixel is (fx·m_x + cx, fy·m_y + cy);
* ``jacobian(x, y, coeffs)``: (∂m_x/∂x, ∂m_x/∂y, ∂m_y/∂x, ∂m_y/∂y) of ``project``;
* ``fold_radius(coeffs)``: the undistorted normalized radius below which ``project`` is one-to-one (inf when
  none is found), the model's valid domain;
* ``maps(K, coeffs, new_K, size)``: float32 rectification maps (raw pixel positions per output pixel).

Modules take plain tuples of floats and never import the calibration type (which imports this registry).
"""
from __future__ import annotations

import importlib
from types import ModuleType

from appdgen.errors import AppdgenError

#: Supported model names → their module (under appdgen.lens). Adding a model = one module + one entry here.
MODELS: dict[str, str] = {"radtan": "radtan"}


def get(name: str) -> ModuleType:
    """The module implementing lens model `name`; AppdgenError naming the supported ones otherwise."""
    if name not in MODELS:
        raise AppdgenError(f"lens model {name!r} is not supported; supported: {', '.join(MODELS)}")
    return importlib.import_module(f"appdgen.lens.{MODELS[name]}")


def params(name: str) -> tuple[str, ...]:
    """The coefficient names of lens model `name`, in order."""
    return get(name).PARAMS
