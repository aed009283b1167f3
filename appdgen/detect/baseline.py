"""A camera's baseline reading: the field its scenery reads as under the calibration it was calibrated with (REF),
on a grid of REF's output pixels. A later belief of the same camera maps its own output pixels to REF's (the warp
between the two rectifications) and removes that bias before the solve, whatever that belief's basis."""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from appdgen.calib.calibration import Calibration
from appdgen.detect.model import belief_crop, field_lookup
from appdgen.detect.simulate import CameraMap
from appdgen.errors import AppdgenError
from appdgen.geometry.bend import output_warp
from appdgen.util.atomic import write_file

FORMAT = "appdgen-detect-baseline"
VERSION = 2


@dataclass(frozen=True, eq=False)
class Baseline:
    """The bias field (gy, gx, 2; output px of REF's rectification) on grid_u × grid_v, and where it came from."""

    reference: Calibration
    max_fov: float | None
    grid_u: np.ndarray
    grid_v: np.ndarray
    field: np.ndarray
    frames: int
    segments: int
    source: str
    camera_map: CameraMap | None = None  # None: readings against it are not mapped (too few frames to learn one)

    @classmethod
    def record(cls, reference: Calibration, max_fov: float | None, grid_u: np.ndarray, grid_v: np.ndarray,
               field: np.ndarray, frames: int, segments: int, source: str,
               camera_map: CameraMap | None = None) -> Baseline:
        """A baseline from a reading under REF (field: the field read, output px) and the camera's map."""
        return cls(reference, max_fov, np.asarray(grid_u, float), np.asarray(grid_v, float),
                   np.asarray(field, float), frames, segments, source, camera_map)

    def with_map(self, camera_map: CameraMap | None) -> Baseline:
        """This baseline with the camera's map."""
        return Baseline(self.reference, self.max_fov, self.grid_u, self.grid_v, self.field, self.frames,
                        self.segments, self.source, camera_map)

    def check(self, belief: Calibration) -> None:
        """AppdgenError unless the belief is of this baseline's camera (raw size and lens model)."""
        if belief.size != self.reference.size or belief.model != self.reference.model:
            raise AppdgenError(
                f"baseline from {self.source}: recorded for a {self.reference.width}x{self.reference.height} "
                f"{self.reference.model} camera, but the calibration is a {belief.width}x{belief.height} "
                f"{belief.model} camera")

    def bias_at(self, belief: Calibration, max_fov: float | None, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The recorded bias (N, 2; output px) where belief output pixels (u, v) show REF's rectification."""
        if u.size == 0:
            return np.zeros((0, 2))
        ref_crop = belief_crop(self.reference, self.max_fov)
        qu, qv = output_warp(self.reference, ref_crop, belief, belief_crop(belief, max_fov), u, v)
        return field_lookup(self.grid_u, self.grid_v, self.field[None], qu, qv)[0]

    def to_json(self, path: Path) -> None:
        """Write the baseline as JSON (atomically)."""
        doc = {"format": FORMAT, "version": VERSION, "source": self.source, "frames": self.frames,
               "segments": self.segments, "max_fov": self.max_fov, "reference": self.reference.to_dict(),
               "grid_u": self.grid_u.tolist(), "grid_v": self.grid_v.tolist(),
               "field": np.round(self.field, 5).tolist(),
               "camera_map": None if self.camera_map is None else self.camera_map.to_dict()}
        write_file(Path(path), (json.dumps(doc) + "\n").encode())

    @classmethod
    def from_json(cls, path: Path) -> Baseline:
        """Read a baseline written by to_json; AppdgenError '<path>: <problem>' on a bad or foreign file."""
        path = Path(path)
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except OSError as exc:
            raise AppdgenError(f"{path}: cannot read: {exc.strerror or exc}") from None
        except (UnicodeDecodeError, json.JSONDecodeError):
            raise AppdgenError(f"{path}: not a JSON file") from None
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            raise AppdgenError(f"{path}: not an appdgen detect baseline (no \"format\": \"{FORMAT}\")")
        if doc.get("version") != VERSION:
            raise AppdgenError(f"{path}: baseline version {doc.get('version')!r}, but this appdgen reads version "
                               f"{VERSION} (with the camera's map): save it again with appdgen detect --save-baseline")
        try:
            ref = dict(doc["reference"])
            width, height, model = ref.pop("width"), ref.pop("height"), ref.pop("model")
            reference = Calibration(width, height, ref.pop("fx"), ref.pop("fy"), ref.pop("cx"), ref.pop("cy"),
                                    model=model, **ref)
            grid_u, grid_v = np.array(doc["grid_u"], float), np.array(doc["grid_v"], float)
            field = np.array(doc["field"], float)
            max_fov = doc["max_fov"]
            if field.shape != (grid_v.size, grid_u.size, 2) or grid_u.size < 2 or grid_v.size < 2:
                raise ValueError("field shape")
            if not np.isfinite(field).all():
                raise ValueError("non-finite field")
            camera_map = None if doc["camera_map"] is None else CameraMap.from_dict(doc["camera_map"])
            return cls(reference, None if max_fov is None else float(max_fov), grid_u, grid_v, field,
                       int(doc["frames"]), int(doc["segments"]), str(doc["source"]), camera_map)
        except AppdgenError as exc:
            raise AppdgenError(f"{path}: {exc}") from None
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise AppdgenError(f"{path}: malformed baseline ({exc})") from None
