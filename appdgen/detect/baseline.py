"""A camera's baseline reading: the field its scenery reads as under the calibration it was calibrated with (REF),
on a grid of REF's output pixels. A later belief of the same camera maps its own output pixels to REF's (the warp
between the two rectifications) and removes that bias before the solve, whatever that belief's basis. The spread of
the baseline frames' own readings around it (principal fields) tells the error model how much, and in which
directions, another view of the same scenery moves a reading."""
from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from appdgen.calib.calibration import Calibration
from appdgen.detect.model import FieldModel, belief_crop, field_lookup
from appdgen.detect.simulate import CameraMap
from appdgen.errors import AppdgenError
from appdgen.geometry.bend import output_warp
from appdgen.util.atomic import write_file

FORMAT = "appdgen-detect-baseline"
VERSION = 5  # 5: edges localised with less smoothing (EdgeParams.sigma 0.7); 4: the third-order field lookup


@dataclass(frozen=True, eq=False)
class Baseline:
    """The bias field (gy, gx, 2; output px of REF's rectification) on grid_u × grid_v, the spread of its frames'
    readings around it, and where it came from."""

    reference: Calibration
    max_fov: float | None
    grid_u: np.ndarray
    grid_v: np.ndarray
    field: np.ndarray
    frames: int
    segments: int
    source: str
    camera_map: CameraMap | None = None  # None: readings against it are not mapped (too few frames to learn one)
    #: (M, gy, gx, 2) principal fields of the frames' readings around `field` (output px): their covariance is
    #: Σ_m s_m s_mᵀ; None: too few frames read alone
    spread: np.ndarray | None = None

    @classmethod
    def record(cls, reference: Calibration, max_fov: float | None, grid_u: np.ndarray, grid_v: np.ndarray,
               field: np.ndarray, frames: int, segments: int, source: str,
               per_frame: np.ndarray | None = None) -> Baseline:
        """A baseline from a reading under REF (field: the pooled frames' field, output px) and the fields its frames
        read alone (per_frame (M, gy, gx, 2); fewer than 3: no spread)."""
        return cls(reference, max_fov, np.asarray(grid_u, float), np.asarray(grid_v, float),
                   np.asarray(field, float), frames, segments, source,
                   spread=None if per_frame is None else principal_spread(np.asarray(per_frame, float)))

    def with_map(self, camera_map: CameraMap | None) -> Baseline:
        """This baseline with the camera's map."""
        return replace(self, camera_map=camera_map)

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
        return self._seen(self.field[None], belief, max_fov, u, v)[:, 0]

    def _seen(self, fields: np.ndarray, belief: Calibration, max_fov: float | None, u: np.ndarray, v: np.ndarray
              ) -> np.ndarray:
        """Fields (M, gy, gx, 2) recorded on REF's grid where belief output pixels (u, v) show REF's
        rectification: (N, M, 2), output px."""
        ref_crop = belief_crop(self.reference, self.max_fov)
        qu, qv = output_warp(self.reference, ref_crop, belief, belief_crop(belief, max_fov), u, v)
        first, rest = field_lookup(self.grid_u, self.grid_v, fields, qu, qv)
        return np.concatenate([first[:, None], rest], axis=1)

    def spread_in(self, model: FieldModel, belief: Calibration, max_fov: float | None) -> np.ndarray | None:
        """The frames' spread as a belief's model reads it: the covariance (K, K; coefficient units, px²) of the
        spread's fields seen at the model's grid nodes, projected on its basis; None without a spread."""
        if self.spread is None:
            return None
        uu, vv = np.meshgrid(model.grid_u, model.grid_v)
        seen = self._seen(self.spread, belief, max_fov, uu.ravel(), vv.ravel()).transpose(1, 0, 2)  # (M, nodes, 2)
        c = seen.reshape(len(seen), -1) @ model.basis.reshape(len(model.basis), -1).T
        return c.T @ c

    def to_json(self, path: Path) -> None:
        """Write the baseline as JSON (atomically)."""
        doc = {"format": FORMAT, "version": VERSION, "source": self.source, "frames": self.frames,
               "segments": self.segments, "max_fov": self.max_fov, "reference": self.reference.to_dict(),
               "grid_u": self.grid_u.tolist(), "grid_v": self.grid_v.tolist(),
               "field": np.round(self.field, 5).tolist(),
               "camera_map": None if self.camera_map is None else self.camera_map.to_dict(),
               "spread": None if self.spread is None else np.round(self.spread, 5).tolist()}
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
                               f"{VERSION}: save it again with appdgen detect --save-baseline")
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
            spread = None if doc["spread"] is None else np.array(doc["spread"], float)
            if spread is not None and (spread.ndim != 4 or spread.shape[1:] != field.shape
                                       or not np.isfinite(spread).all()):
                raise ValueError("spread shape")
            return cls(reference, None if max_fov is None else float(max_fov), grid_u, grid_v, field,
                       int(doc["frames"]), int(doc["segments"]), str(doc["source"]), camera_map, spread)
        except AppdgenError as exc:
            raise AppdgenError(f"{path}: {exc}") from None
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise AppdgenError(f"{path}: malformed baseline ({exc})") from None


def principal_spread(per_frame: np.ndarray) -> np.ndarray | None:
    """(M, gy, gx, 2) principal fields s_m of fields (n, gy, gx, 2) around their mean, Σ_m s_m s_mᵀ their sample
    covariance (output px); None for fewer than 3 fields or when they do not differ (no spread to keep: an empty
    one would not survive the file)."""
    n = len(per_frame)
    if n < 3:
        return None
    flat = per_frame.reshape(n, -1)
    _, sv, vt = np.linalg.svd(flat - flat.mean(0), full_matrices=False)
    keep = sv > sv[0] * 1e-9
    if not keep.any():
        return None
    return (sv[keep, None] / np.sqrt(n - 1) * vt[keep]).reshape((int(keep.sum()),) + per_frame.shape[1:])
