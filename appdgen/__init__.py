"""appdgen: self-labelled data for learning camera miscalibration detection.

The names a notebook uses, importable from ``appdgen`` itself (README, "Python"): ``load`` (a calibration file),
``Calibration``, ``rectify`` (crop R, K̂ and maps M̂), ``appd`` (the label between two calibrations),
``Sampler`` (perturbed calibrations with about uniform labels), ``BuildConfig`` and ``build`` (a build folder),
``AppdgenError``. All but the two types load on first use: ``import appdgen`` stays as cheap as the calibration
type (numpy, OpenCV), without the file readers' YAML or the build's Arrow.
"""
from __future__ import annotations

import importlib
from typing import Any

from appdgen.calib.calibration import PARAMS, Calibration
from appdgen.errors import AppdgenError
from appdgen.version import __version__

#: Public name → the module that owns it (imported on first use).
_LAZY = {"load": "appdgen.calib.formats", "rectify": "appdgen.geometry.maps", "appd": "appdgen.geometry.appd",
         "Sampler": "appdgen.sampling.sampler", "BuildConfig": "appdgen.dataset.plan",
         "build": "appdgen.dataset.build", "open_build": "appdgen.dataset.reader"}
__all__ = ["AppdgenError", "BuildConfig", "Calibration", "PARAMS", "Sampler", "__version__", "appd", "build", "load",
           "open_build", "rectify"]


def __getattr__(name: str) -> Any:
    """A lazily imported public name, from the module that owns it."""
    if name not in _LAZY:
        raise AttributeError(f"module 'appdgen' has no attribute {name!r}")
    value = getattr(importlib.import_module(_LAZY[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    """The module's names, the lazy ones included."""
    return sorted({*globals(), *_LAZY})
