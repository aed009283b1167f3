"""Read and write camera calibration files: the one entry (``load``, ``list_cameras``, ``save``) over the format
families' modules (parsing only: no geometry here).

``load`` recognises the format from the content, not the extension, and the lens model from the file; each family
says what it reads in its own module: ``kitti`` (KITTI raw calib_cam_to_cam.txt), ``opencv`` (OpenCV FileStorage
YAML/XML, ROS camera_info), ``kalibr`` (Kalibr camchain, EuRoC sensor.yaml), ``basalt`` (Basalt calibration.json),
``nuscenes`` (calibrated_sensor.json) and ``native`` (appdgen JSON). Adding a format is one module with a
``recognise`` (document → Found or None) and a line in RECOGNISERS.

Camera names (``list_cameras``) and ``camera=``: each family names its cameras (KITTI ``'00'`` … ``'03'``, Kalibr
``'cam0'`` …, Basalt ``'cam0'`` … by index, nuScenes ``'0'`` … by index among camera records; one-camera files
``'0'``). ``camera`` matches a name exactly or by number, so ``2``, ``'2'``, ``'02'``, ``'image_02'`` and
``'cam2'`` all pick KITTI ``'02'``, and ``'0'`` picks Kalibr ``'cam0'``. ``camera=None`` picks the only camera,
and is an error listing the names when there are several. The image size comes from the file; ``size=(width,
height)`` is needed only where the file has none (it must agree with the file where it has one).

``save`` writes appdgen JSON (every model, exact) or OpenCV FileStorage YAML (radtan, rational, kb4). A rational
calibration whose extra terms are all 0 reads back from YAML as radtan (same maps).

Every failure raises ``AppdgenError`` with one line: ``<path>: <problem>``.
"""
from __future__ import annotations

import os
import re
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from appdgen.calib import basalt, kalibr, kitti, native, nuscenes, opencv
from appdgen.calib.calibration import Calibration
from appdgen.calib.fields import Found, Size, read_size
from appdgen.calib.syntax import parse_json, parse_xml, parse_yaml
from appdgen.errors import AppdgenError
from appdgen.util.atomic import atomic_write

__all__ = ["list_cameras", "load", "native_suffix", "save"]

#: Files larger than this (bytes) are refused unread; a full nuScenes calibrated_sensor.json is ~5 MB.
MAX_BYTES = 64 * 2**20
PathLike = str | os.PathLike[str]

#: The mapping documents' recognisers, in the order they are tried (a document's first match is its format).
RECOGNISERS: tuple[Callable[[dict[Any, Any]], Found | None], ...] = (
    native.recognise, kalibr.recognise_camchain, basalt.recognise, kalibr.recognise_sensor, opencv.recognise)
#: The writers by file extension.
WRITERS: dict[str, Callable[[Calibration], str]] = {".yaml": opencv.yaml_text, ".yml": opencv.yaml_text,
                                                    ".json": native.json_text}
_CAMERA_NUMBER = re.compile(r"(?:image|camera|cam)?[_ -]?0*([0-9]+)", re.IGNORECASE)
_FORMATS = "KITTI, OpenCV, ROS camera_info, Kalibr, EuRoC, Basalt, nuScenes or appdgen"


def load(path: PathLike, camera: str | int | None = None, size: Size | None = None) -> Calibration:
    """One camera's calibration (size and K in pixels, distortion unitless) from any supported file."""
    with _about(str(path)):
        found = _recognise(path)
        name = _select(list(found.cameras), camera)
        with _about(found.kind + (f" camera {name}" if len(found.cameras) > 1 else "")):
            in_file, K, model, coeffs = found.cameras[name]()
            return _calibration(_chosen_size(in_file, size, found.default_size), K, model, coeffs)


def list_cameras(path: PathLike) -> list[str]:
    """The camera names in a calibration file, in the order ``load(path, camera=…)`` accepts them."""
    with _about(str(path)):
        return list(_recognise(path).cameras)


def calibration_topic(path: PathLike, camera: str | int | None = None) -> str | None:
    """The ROS image topic a Kalibr camchain names for a camera (its ``rostopic``), None for files without one."""
    with _about(str(path)):
        found = _recognise(path)
        return found.topics.get(_select(list(found.cameras), camera))


def native_suffix(calib: Calibration) -> str:
    """The extension to save calib under: .yaml where OpenCV YAML holds its model (radtan, rational, kb4), else
    .json."""
    return ".yaml" if calib.model in opencv.YAML_MODELS else ".json"


def save(calib: Calibration, path: PathLike) -> None:
    """Write atomically by extension: .yaml/.yml → OpenCV FileStorage YAML (radtan, rational, kb4), .json →
    appdgen JSON (every model); exact floats."""
    target = Path(path)
    with _about(str(path)):
        writer = WRITERS.get(target.suffix.lower())
        if writer is None:
            raise AppdgenError(f"cannot write extension {target.suffix or '(none)'!r}; use .yaml, .yml or .json")
        _write_atomic(target, writer(calib))


# --- reading: text, syntax, format ---------------------------------------------------------------------------


def _recognise(path: PathLike) -> Found:
    """Read the file and recognise its format and cameras."""
    return _detect(_read_text(Path(path)))


def _read_text(path: Path) -> str:
    """The file's UTF-8 text; missing, unreadable, oversized, binary and empty files are refused."""
    try:
        with path.open("rb") as stream:
            data = stream.read(MAX_BYTES + 1)
    except FileNotFoundError:
        raise AppdgenError("no such file") from None
    except IsADirectoryError:
        raise AppdgenError("is a directory, not a calibration file") from None
    except (OSError, ValueError) as exc:  # ValueError: a NUL byte in the path
        raise AppdgenError(f"cannot read: {getattr(exc, 'strerror', None) or exc}") from None
    if len(data) > MAX_BYTES:
        raise AppdgenError(f"larger than {MAX_BYTES >> 20} MiB: not a calibration file")
    if b"\0" in data:
        raise AppdgenError("binary data (NUL bytes), not a text calibration file")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise AppdgenError(f"not UTF-8 text (byte {exc.start}): not a calibration file") from None
    if not text.strip():
        raise AppdgenError("empty file")
    return text


def _detect(text: str) -> Found:
    """Recognise the format from the text and split it into cameras."""
    first = text.lstrip()[:1]
    if first == "<":
        return _classify(parse_xml(text), "XML")
    if first in ("[", "{"):
        return _classify(parse_json(text), "JSON")
    return kitti.recognise(text) or _classify(parse_yaml(text), "YAML")


def _classify(doc: Any, syntax: str) -> Found:
    """Recognise a parsed YAML, JSON or XML document by its shape and keys."""
    found = nuscenes.recognise(doc) if isinstance(doc, list) else _by_keys(doc) if isinstance(doc, dict) else None
    if found is None:
        raise AppdgenError(f"unknown calibration format (read as {syntax}; expected {_FORMATS})")
    return found


def _by_keys(doc: dict[Any, Any]) -> Found | None:
    """The first of RECOGNISERS that knows the mapping document, or None."""
    for recognise in RECOGNISERS:
        found = recognise(doc)
        if found is not None:
            return found
    return None


# --- reading: one camera, checked ----------------------------------------------------------------------------


def _calibration(size: Size, K: np.ndarray, model: str, coeffs: np.ndarray) -> Calibration:
    """The validated Calibration from image size (pixels), 3×3 K (pixels), lens model and its coefficients."""
    if K.shape != (3, 3):
        raise AppdgenError(f"camera matrix: expected 3x3, got {'x'.join(map(str, K.shape))}")
    if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
        raise AppdgenError("camera matrix: expected the form [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (transposed?)")
    try:
        return Calibration.from_arrays(size[0], size[1], K, coeffs, model=model)
    except AppdgenError as exc:
        raise AppdgenError(str(exc).removeprefix("calibration: ")) from None


def _chosen_size(in_file: Size | None, given: Any, default: Size | None) -> Size:
    """The file's image size (pixels), else `given`, else the format's default; a disagreement is an error."""
    if given is not None:
        given = read_size("size", list(given) if isinstance(given, (tuple, np.ndarray)) else given)
        if in_file is not None and given != in_file:
            raise AppdgenError(f"size {given[0]}x{given[1]} given, but the file says {in_file[0]}x{in_file[1]}")
    chosen = in_file or given or default
    if chosen is None:
        raise AppdgenError("no image size in the file; pass size=(width, height)")
    return chosen


def _select(names: list[str], camera: str | int | None) -> str:
    """The camera name that `camera` picks (exactly or by number); None picks the only camera."""
    if not names:
        raise AppdgenError("no camera in the file")
    if camera is None:
        if len(names) == 1:
            return names[0]
        raise AppdgenError(f"{len(names)} cameras; choose one with --camera (camera= in Python); "
                           f"available: {_listing(names)}")
    wanted = str(camera).strip()
    number = _camera_number(wanted)
    matches = [n for n in names if n == wanted] or [n for n in names if number and _camera_number(n) == number]
    if len(matches) != 1:
        raise AppdgenError(f"camera {wanted!r} not found; available: {_listing(names)}")
    return matches[0]


def _camera_number(name: str) -> str | None:
    """The number in a camera name without leading zeros ('image_02' → '2'), or None."""
    match = _CAMERA_NUMBER.fullmatch(name)
    return match.group(1) if match else None


def _listing(names: list[str], most: int = 12) -> str:
    """Camera names for a message, cut short after `most`."""
    shown = ", ".join(names[:most])
    return shown if len(names) <= most else f"{shown}, … ({len(names)} in all)"


@contextmanager
def _about(subject: str) -> Iterator[None]:
    """Re-raise an AppdgenError from inside as one line prefixed with ``subject: ``."""
    try:
        yield
    except AppdgenError as exc:
        raise AppdgenError(" ".join(f"{subject}: {exc}".splitlines())) from None


# --- writing ---------------------------------------------------------------------------------------------------


def _write_atomic(target: Path, text: str) -> None:
    """Write text atomically, turning OS failures into AppdgenError."""
    try:
        atomic_write(target, text.encode("utf-8"))
    except OSError as exc:
        raise AppdgenError(f"cannot write: {exc.strerror or exc}") from None
