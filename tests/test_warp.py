"""The device renderer (train.warp) against cv2.remap(INTER_CUBIC, BORDER_REFLECT_101), build's remap, on CPU torch.

Bounds measured on white noise (the hardest texture: neighbouring pixels independent) at a quarter of each
camera's size, with rectify()'s float32 maps:

* uint8 frames: at most 1 level apart (rounding of values near .5), mean ≤ 0.0054 levels (rational8);
  with the maps computed on the device (rectify_batch) mean ≤ 0.0091 levels;
* float32 frames: at most 0.096 levels apart (0–255 scale), both a = −0.75 bicubic.
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest
from test_lens import CAMERAS

from appdgen.geometry.maps import rectify

torch = pytest.importorskip("torch")
from train.errors import TrainError  # noqa: E402  (after the torch check: train needs torch)
from train.warp import maps_batch, rectify_batch, remap_batch  # noqa: E402

MAX_FOV = {"kb4": 120.0}


def noise(size: tuple[int, int], seed: int) -> np.ndarray:
    """White-noise BGR uint8 frame of size (w, h)."""
    return np.random.default_rng(seed).integers(0, 256, (size[1], size[0], 3), dtype=np.uint8)


def to_tensor(images: list[np.ndarray]) -> torch.Tensor:
    """H×W×C numpy frames → N×C×H×W tensor."""
    return torch.from_numpy(np.stack(images)).permute(0, 3, 1, 2).contiguous()


def to_images(batch: torch.Tensor) -> np.ndarray:
    """N×C×h×w tensor → N×h×w×C numpy."""
    return batch.permute(0, 2, 3, 1).numpy()


def cv2_cubic(image: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    """build's remap with cubic interpolation (appdgen.geometry.remap.remap_image's border)."""
    return cv2.remap(image, map_x, map_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT_101)


@pytest.mark.parametrize("name", ["radtan", "rational8", "kb4", "eucm"])
def test_device_image_matches_cv2_remap_cubic(name):
    calib = CAMERAS[name]
    size = (calib.width // 4, calib.height // 4)
    rect = rectify(calib, size, max_fov=MAX_FOV.get(name))
    image = noise(calib.size, 3)
    reference = cv2_cubic(image, rect.map_x, rect.map_y).astype(int)
    maps = torch.from_numpy(rect.map_x)[None], torch.from_numpy(rect.map_y)[None]
    same_maps = remap_batch(to_tensor([image]), *maps)
    assert same_maps.dtype == torch.uint8 and same_maps.shape == (1, 3, size[1], size[0])
    diff = np.abs(to_images(same_maps)[0].astype(int) - reference)
    assert diff.max() <= 1 and diff.mean() <= 0.008, (diff.max(), diff.mean())
    device_maps = rectify_batch(to_tensor([image]), [calib], [rect.new_camera_matrix], size)
    diff = np.abs(to_images(device_maps)[0].astype(int) - reference)
    assert diff.max() <= 1 and diff.mean() <= 0.013, (diff.max(), diff.mean())
    floats = remap_batch(to_tensor([image]).float(), *maps)
    assert floats.dtype == torch.float32
    expected = cv2_cubic(image.astype(np.float32), rect.map_x, rect.map_y)
    assert np.abs(to_images(floats)[0] - expected).max() <= 0.15


def test_border_taps_reflect_like_build():
    # Positions up to 1.5 px past the frame's edge pixels: the kernel taps beyond it mirror about the edge
    # pixels' centres (BORDER_REFLECT_101), not clamp or zero.
    image = noise((24, 16), 1)
    xs, ys = np.linspace(-1.5, 24.5, 40, dtype=np.float32), np.linspace(-1.5, 16.5, 30, dtype=np.float32)
    map_x, map_y = np.meshgrid(xs, ys)
    out = remap_batch(to_tensor([image]).float(), torch.from_numpy(map_x)[None], torch.from_numpy(map_y)[None])
    expected = cv2_cubic(image.astype(np.float32), map_x, map_y)
    assert np.abs(to_images(out)[0] - expected).max() <= 0.15


def test_integer_maps_give_the_frame_back():
    image = noise((20, 12), 2)
    map_x, map_y = np.meshgrid(np.arange(20, dtype=np.float32), np.arange(12, dtype=np.float32))
    out = remap_batch(to_tensor([image, image[::-1].copy()]), torch.from_numpy(np.stack([map_x] * 2)),
                      torch.from_numpy(np.stack([map_y] * 2)))
    assert np.array_equal(to_images(out), np.stack([image, image[::-1]]))


def test_batch_rows_take_their_own_calibration():
    calib = CAMERAS["radtan"]
    size = (calib.width // 8, calib.height // 8)
    other = calib.replace(k1=calib.k1 + 0.05, fx=calib.fx * 1.02)
    rects = [rectify(c, size) for c in (calib, other)]
    frames = [noise(calib.size, 4), noise(calib.size, 5)]
    out = to_images(rectify_batch(to_tensor(frames), [calib, other], [r.new_camera_matrix for r in rects], size))
    for got, frame, rect in zip(out, frames, rects, strict=True):
        assert np.abs(got.astype(int) - cv2_cubic(frame, rect.map_x, rect.map_y)).max() <= 1
    map_x, _ = maps_batch([calib, other], [r.new_camera_matrix for r in rects], size, dtype=torch.float64)
    assert map_x.dtype == torch.float64 and np.abs(map_x[1].numpy() - rects[1].map_x).max() <= 2e-4


def test_device_renderer_refuses_what_it_cannot_do():
    calib = CAMERAS["radtan"]
    rect = rectify(calib, (32, 12))
    frames = to_tensor([noise(calib.size, 1)])
    with pytest.raises(TrainError, match="interpolation 'lanczos4' is not available on the device"):
        rectify_batch(frames, [calib], [rect.new_camera_matrix], (32, 12), interp="lanczos4")
    with pytest.raises(TrainError, match="frames are 1392x512 but a calibration is 696x256"):
        rectify_batch(frames, [calib.replace(width=696, height=256)], [rect.new_camera_matrix], (32, 12))
    with pytest.raises(TrainError, match="for 2 calibrations"):
        rectify_batch(frames, [calib, calib], [rect.new_camera_matrix] * 2, (32, 12))
    with pytest.raises(TrainError, match="one lens model per batch"):
        maps_batch([calib, CAMERAS["kb4"]], [rect.new_camera_matrix] * 2, (32, 12))
