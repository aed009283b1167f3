"""Device maps (geometry.maps.raw_positions): the lens layer's own projections in torch equal rectify()'s maps.

The reference is rectify(): OpenCV's initUndistortRectifyMap for radtan and rational, appdgen's numpy float32 maps
for kb4, ds and eucm. Float32 on the device keeps ≤ 1e-3 px; what it loses is the rounding of the pixel position
itself (1–2 ulp of the raw coordinate, see raw_positions_batch's docstring).
"""
from __future__ import annotations

import functools
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from test_lens import CAMERAS

from appdgen.calib.calibration import Calibration
from appdgen.errors import AppdgenError
from appdgen.geometry.crop import Crop, valid_region
from appdgen.geometry.maps import raw_positions, raw_positions_batch, rectify

torch = pytest.importorskip("torch")

#: TUM VI's kb4 lens sees past 115° inside its frame: its crop needs a bounded field of view.
MAX_FOV = {"kb4": 120.0}


@functools.cache
def crop_of(name: str) -> Crop:
    """The reference camera's valid region (computed once per test session)."""
    return valid_region(CAMERAS[name], max_fov=MAX_FOV.get(name))


def worst(maps: tuple, rect) -> float:
    """Largest |difference| (raw pixels) between device maps and a Rectification's maps."""
    mx, my = (np.asarray(m.cpu().numpy() if hasattr(m, "cpu") else m, dtype=np.float64) for m in maps)
    return float(max(np.abs(mx - rect.map_x).max(), np.abs(my - rect.map_y).max()))


@pytest.mark.parametrize("name", sorted(CAMERAS))
@pytest.mark.parametrize("divisor", [4, 2])
def test_device_maps_equal_rectify_maps(name, divisor):
    calib = CAMERAS[name]
    size = (calib.width // divisor, calib.height // divisor)
    rect = rectify(calib, size, crop=crop_of(name))
    ulp = float(np.spacing(np.float32(max(calib.size))))  # float32 spacing at the largest raw coordinate
    f32 = worst(raw_positions(calib, rect.new_camera_matrix, size, like=torch.empty(0)), rect)
    f64 = worst(raw_positions(calib, rect.new_camera_matrix, size, like=torch.empty(0, dtype=torch.float64)), rect)
    # Measured: float32 ≤ 2 ulp (2.4e-4 px at 1392 wide, 4.9e-4 px at 2880); float64 ≤ 2 ulp, which is the
    # reference maps' own float32 rounding (½ ulp for OpenCV's, up to 2 ulp for the numpy float32 ones).
    assert f32 <= min(1e-3, 2.5 * ulp), (name, size, f32)
    assert f64 <= min(2e-4, 2.5 * ulp), (name, size, f64)
    assert f32 > 0.0  # float32 differs from the float64 reference somewhere: the comparison is not vacuous


def perturbed(calib: Calibration, rng: np.random.Generator) -> Calibration:
    """The calibration with its intrinsics and coefficients changed by a few percent (a stand-in Θm)."""
    params = {n: v * (1.0 + 0.03 * rng.standard_normal()) + 0.002 * rng.standard_normal()
              for n, v in calib.params().items()}
    return calib.replace(**params)


@pytest.mark.parametrize("name", ["radtan", "kb4"])
def test_batched_maps_hold_one_calibration_per_row(name):
    rng = np.random.default_rng(5)
    reference = CAMERAS[name]
    calibs = [perturbed(reference, rng) for _ in range(3)]
    size = (reference.width // 4, reference.height // 4)
    # Each row its own crop (so K̂ differs per row too): the reference's, shrunk about the axis.
    box = crop_of(name)
    crops = [Crop(box.x0 * f, box.y0 * f, box.x1 * f, box.y1 * f) for f in (1.0, 0.9, 0.8)]
    rects = [rectify(c, size, crop=k) for c, k in zip(calibs, crops, strict=True)]
    map_x, map_y = raw_positions_batch(calibs, [r.new_camera_matrix for r in rects], size,
                                       like=torch.empty(0, dtype=torch.float64))
    assert map_x.shape == (3, size[1], size[0])
    for i, rect in enumerate(rects):
        assert worst((map_x[i], map_y[i]), rect) <= 2e-4
    assert worst((map_x[0], map_y[0]), rects[1]) > 0.1  # rows really differ
    chunked = raw_positions_batch(calibs, [r.new_camera_matrix for r in rects], size,
                                  like=torch.empty(0, dtype=torch.float64), chunk=2)
    assert torch.equal(chunked[0], map_x) and torch.equal(chunked[1], map_y)


def test_numpy_namespace_gives_the_same_maps():
    calib = CAMERAS["eucm"]
    size = (calib.width // 4, calib.height // 4)
    rect = rectify(calib, size, crop=crop_of("eucm"))
    map_x, map_y = raw_positions(calib, rect.new_camera_matrix, size, like=np.empty(0))
    assert isinstance(map_x, np.ndarray) and map_x.shape == (size[1], size[0])
    assert worst((map_x, map_y), rect) <= 2e-4


def test_batches_refuse_mixed_models_and_counts():
    k = np.eye(3)
    with pytest.raises(AppdgenError, match="one lens model per batch"):
        raw_positions_batch([CAMERAS["radtan"], CAMERAS["kb4"]], [k, k], (8, 8), like=torch.empty(0))
    with pytest.raises(AppdgenError, match="2 calibrations but 1 camera matrices"):
        raw_positions_batch([CAMERAS["radtan"]] * 2, [k], (8, 8), like=torch.empty(0))
    with pytest.raises(AppdgenError, match="floating dtype"):
        raw_positions_batch([CAMERAS["radtan"]], [k], (8, 8), like=torch.empty(0, dtype=torch.int32))


def test_appdgen_maps_run_without_torch():
    # A finder that refuses torch, as on a machine without it: the lens layer and numpy maps must not need it.
    script = textwrap.dedent("""
        import sys
        class NoTorch:
            def find_spec(self, name, path=None, target=None):
                if name == "torch" or name.startswith("torch."):
                    raise ImportError("no torch here")
        sys.meta_path.insert(0, NoTorch())
        import numpy as np
        from appdgen.calib.calibration import Calibration
        from appdgen.geometry.maps import raw_positions, rectify
        c = Calibration(64, 48, 50.0, 50.0, 32.0, 24.0, -0.2, 0.05)
        r = rectify(c, (32, 24))
        mx, my = raw_positions(c, r.new_camera_matrix, (32, 24), like=np.empty(0))
        assert np.abs(mx - r.map_x).max() < 1e-4 and "torch" not in sys.modules
        print("ok")
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr
