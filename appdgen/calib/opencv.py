"""OpenCV FileStorage (YAML and XML) and ROS ``camera_info``: read, and write as OpenCV FileStorage YAML.

Keys ``camera_matrix``, ``distortion_coefficients`` (1×N or N×1), ``image_width``/``image_height`` (any case).
OpenCV's distortion vector (4, 5, 8, 12 or 14 numbers) becomes the smallest model that holds it exactly: radtan
when every term past k3 is 0, else rational (k4 k5 k6, thin prism s1..s4); the tilted model (14 numbers with a
non-zero τx or τy) is refused. ``distortion_model: fisheye`` or ``equidistant`` marks ``cv2.fisheye``'s model:
kb4, exactly 4 numbers (k1..k4). ROS's plumb_bob and rational_polynomial take the vector as above (as ROS hands
it to OpenCV: a rational_polynomial file whose extra terms are all 0 is radtan, the same geometry). One camera,
named ``'0'``. Written: radtan 5 numbers; rational 8, or 12 with thin prism; kb4 4 numbers and
``distortion_model: fisheye``; OpenCV has no ds or eucm, so those are refused.
"""
from __future__ import annotations

from functools import partial
from typing import Any

import numpy as np

from appdgen import lens
from appdgen.calib.calibration import DEFAULT_MODEL, Calibration
from appdgen.calib.fields import Found, Parts, allowed, as_mapping, counted, need, number, numbers, optional_size
from appdgen.errors import AppdgenError

#: OpenCV/ROS ``distortion_model`` values → the model, None meaning "by the length of OpenCV's vector".
_OPENCV_MODELS: dict[str, str | None] = {"plumb_bob": None, "rational_polynomial": None, "equidistant": "kb4",
                                         "fisheye": "kb4"}
#: OpenCV's distortion vector: lengths it takes, and where the terms beyond radtan's five end for each model.
_OPENCV_LENGTHS = (4, 5, 8, 12, 14)
_TILT = 12
#: Models OpenCV FileStorage YAML can hold, and the ``distortion_model`` written for them (None: none written).
YAML_MODELS: dict[str, str | None] = {DEFAULT_MODEL: None, "rational": None, "kb4": "fisheye"}


def recognise(doc: dict[Any, Any]) -> Found | None:
    """An OpenCV FileStorage or ROS camera_info document (a ``camera_matrix`` key in any case), or None."""
    lowered = {k.lower(): v for k, v in doc.items() if isinstance(k, str)}
    if "camera_matrix" in lowered:
        return Found("OpenCV/ROS", {"0": partial(_camera, lowered)})
    return None


def _camera(doc: dict[str, Any]) -> Parts:
    """Size, K, model and coefficients from OpenCV FileStorage or ROS camera_info keys (lower-cased)."""
    flavour = doc.get("distortion_model", "plumb_bob")
    allowed("distortion_model", flavour, tuple(_OPENCV_MODELS))
    K = _cv_matrix("camera_matrix", doc["camera_matrix"])
    D = _cv_matrix("distortion_coefficients", need(doc, "distortion_coefficients"))
    if 1 not in D.shape:
        raise AppdgenError(f"distortion_coefficients: expected 1xN or Nx1, got {D.shape[0]}x{D.shape[1]}")
    model = _OPENCV_MODELS[flavour]
    if model is None:
        model, coeffs = _opencv_vector(D.ravel())
    else:
        coeffs = counted(f"distortion_coefficients ({flavour}: {', '.join(lens.params(model))})", D.ravel(),
                         len(lens.params(model)))
    return optional_size(doc, "image_width", "image_height"), K, model, coeffs


def _opencv_vector(D: np.ndarray) -> tuple[str, np.ndarray]:
    """OpenCV's distortion vector → the smallest model holding it exactly: radtan, else rational; tilt refused."""
    D = counted("distortion_coefficients", D, *_OPENCV_LENGTHS)
    if np.any(D[_TILT:] != 0):
        raise AppdgenError("OpenCV's tilted model (14 distortion coefficients with a non-zero tau_x or tau_y) "
                           "is not supported")
    radtan = len(lens.params(DEFAULT_MODEL))
    if np.all(D[radtan:] == 0):
        return DEFAULT_MODEL, D[:radtan]
    return "rational", D[:_TILT]


def _cv_matrix(what: str, node: Any) -> np.ndarray:
    """A rows×cols array from an OpenCV/ROS matrix node {rows, cols, data}."""
    node = as_mapping(what, node)
    rows, cols = (number(f"{what}.{k}", need(node, k, what)) for k in ("rows", "cols"))
    if not (rows.is_integer() and cols.is_integer() and rows >= 1 and cols >= 1):
        raise AppdgenError(f"{what}: rows and cols must be positive whole numbers, got {rows:g} and {cols:g}")
    return numbers(f"{what}.data", need(node, "data", what), (int(rows) * int(cols),)).reshape(int(rows), int(cols))


def yaml_text(calib: Calibration) -> str:
    """OpenCV FileStorage YAML (``%YAML:1.0``, as OpenCV 4 writes it) with shortest exact float reprs."""
    if calib.model not in YAML_MODELS:
        raise AppdgenError(f"OpenCV YAML cannot hold lens model {calib.model!r} (OpenCV has no such model); "
                           "save it as .json")
    flavour = YAML_MODELS[calib.model]
    head = f"image_width: {calib.width}\nimage_height: {calib.height}\n"
    head += f"distortion_model: {flavour}\n" if flavour else ""
    D = calib.D
    if calib.model == "rational" and np.all(D[8:] == 0):
        D = D[:8]  # OpenCV's 8-coefficient rational vector; 12 only when the thin-prism terms are used
    return "%YAML:1.0\n---\n" + head + _cv_matrix_text("camera_matrix", calib.K) + _cv_matrix_text(
        "distortion_coefficients", D.reshape(1, -1)
    )


def _cv_matrix_text(name: str, matrix: np.ndarray) -> str:
    """One ``!!opencv-matrix`` node of doubles."""
    data = ", ".join(repr(float(v)) for v in matrix.ravel())
    rows, cols = matrix.shape
    return f"{name}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ {data} ]\n"
