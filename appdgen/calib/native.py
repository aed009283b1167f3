"""appdgen's own JSON calibration: read and write, every lens model, exact floats.

Version 2 has ``model`` and that model's parameter names; version 1 (no ``model``) is radtan. One camera, ``'0'``.
"""
from __future__ import annotations

import json
from functools import partial
from typing import Any

import numpy as np

from appdgen import lens
from appdgen.calib.calibration import DEFAULT_MODEL, INTRINSICS, Calibration
from appdgen.calib.fields import Found, Parts, k_matrix, need, number, optional_size, short
from appdgen.errors import AppdgenError

#: The ``format`` field of appdgen JSON calibration files.
APPDGEN_FORMAT = "appdgen-calibration"
#: The appdgen JSON version ``save`` writes (2: with ``model``); version 1 (radtan, no ``model``) is still read.
APPDGEN_VERSION = 2


def recognise(doc: dict[Any, Any]) -> Found | None:
    """An appdgen JSON document (its ``format`` tag), or None."""
    if doc.get("format") == APPDGEN_FORMAT:
        return Found("appdgen JSON", {"0": partial(_camera, doc)})
    return None


def _camera(doc: dict[str, Any]) -> Parts:
    """Size, K, model and coefficients from appdgen JSON (version 2; version 1 is radtan without ``model``)."""
    version = doc.get("version")
    if version not in (1, APPDGEN_VERSION) or isinstance(version, bool):
        raise AppdgenError(f"unsupported {APPDGEN_FORMAT} version {short(version)}; "
                           f"expected 1 or {APPDGEN_VERSION}")
    model = DEFAULT_MODEL if version == 1 else need(doc, "model")
    if not isinstance(model, str):
        raise AppdgenError(f"model: expected a lens model name, got {short(model)}")
    fx, fy, cx, cy, *coeffs = (number(name, need(doc, name)) for name in (*INTRINSICS, *lens.params(model)))
    return optional_size(doc, "width", "height"), k_matrix(fx, fy, cx, cy), model, np.array(coeffs)


def json_text(calib: Calibration) -> str:
    """appdgen JSON (version 2): format tag, version, model, size and the model's parameters, exact float reprs."""
    fields = calib.to_dict()
    header = {"format": APPDGEN_FORMAT, "version": APPDGEN_VERSION, "model": fields.pop("model")}
    return json.dumps({**header, **fields}, indent=2) + "\n"
