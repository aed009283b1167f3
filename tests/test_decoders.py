"""Strict decoders (sources/decode.py): OpenCV's pixels for good JPEGs, and a corrupt JPEG body (which
cv2.imdecode returns as an image, with only a libjpeg warning) named in one line or, with --skip-bad, skipped and
counted: in an image folder and in a bag's CompressedImage."""
from __future__ import annotations

import ast
import json
from pathlib import Path

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest

from appdgen.errors import AppdgenError
from appdgen.sources.decode import decode_bytes
from appdgen.sources.inputs import iter_images, resolve_inputs
from helpers import assert_one_line_error, compressed_bag, kitti_text, raw_image, run_cli, write_png

START_NS = 1_600_000_000_000_000_000
ROOT = Path(__file__).resolve().parents[1]
#: Decoders of encoded images, which only appdgen/sources/ calls on raw frames.
DECODERS = {("cv2", "imread"), ("cv2", "imdecode"), ("simplejpeg", "decode_jpeg")}
#: Modules that decode what appdgen itself wrote, not raw frames: synth's PNG frames rewritten as a recording, and a
#: build's samples read back (dataset/images.py) and checked (dataset/verify.py).
OWN_OUTPUTS = {"synth/recording.py", "dataset/images.py", "dataset/verify.py"}


def jpeg(image: np.ndarray, quality: int = 90) -> bytes:
    """JPEG bytes of an image (OpenCV's encoder, 4:2:0 for colour)."""
    return cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])[1].tobytes()


def corrupt(data: bytes) -> bytes:
    """200 bytes in the middle of the entropy-coded body overwritten with random ones (header and end intact)."""
    damaged = bytearray(data)
    middle = len(damaged) // 2
    damaged[middle:middle + 200] = np.random.default_rng(0).integers(0, 256, 200, dtype=np.uint8).tobytes()
    return bytes(damaged)


@pytest.mark.parametrize("channels", [1, 3, None])
@pytest.mark.parametrize("source", ["colour", "grey"])
def test_good_jpegs_decode_to_opencvs_pixels(source: str, channels: int | None) -> None:
    image = raw_image((348, 128), 5)
    data = jpeg(image if source == "colour" else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))
    flag = {1: cv2.IMREAD_GRAYSCALE, 3: cv2.IMREAD_COLOR, None: cv2.IMREAD_UNCHANGED}[channels]
    expected = cv2.imdecode(np.frombuffer(data, np.uint8), flag)
    assert np.array_equal(decode_bytes(data, "x.jpg", channels), expected)


def test_a_corrupt_body_opencv_reads_silently_is_an_error_naming_the_file() -> None:
    data = corrupt(jpeg(raw_image((348, 128), 5)))
    assert cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR) is not None  # OpenCV: an image, no error
    with pytest.raises(AppdgenError, match=r"^frames/a\.jpg: corrupt JPEG \(Corrupt JPEG data"):
        decode_bytes(data, "frames/a.jpg", 3)


@pytest.fixture
def jpeg_folder(small_camera, tmp_path: Path) -> tuple[Path, Path]:
    """A calibration file and a folder of four JPEG frames, the third with a corrupt body."""
    calib = tmp_path / "calib_cam_to_cam.txt"
    calib.write_text(kitti_text({"02": small_camera}))
    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(4):
        data = jpeg(raw_image(small_camera.size, i))
        (folder / f"{i:06d}.jpg").write_bytes(corrupt(data) if i == 2 else data)
    return calib, folder


def _args(calib: Path, images: Path, out: Path, *extra: str) -> list[str]:
    """A small `appdgen build` (16 samples of 87x32, --jobs 1)."""
    return ["build", "--calib", str(calib), "--images", str(images), "--out", str(out), "--samples", "16",
            "--size", "87x32", "--jobs", "1", "--quiet", *extra]


def test_corrupt_jpeg_in_a_folder_is_named_or_skipped_and_counted(jpeg_folder, tmp_path: Path) -> None:
    calib, folder = jpeg_folder
    bad = folder / "000002.jpg"
    assert_one_line_error(run_cli(_args(calib, folder, tmp_path / "stopped")), str(bad), "corrupt JPEG")
    out = tmp_path / "out"
    result = run_cli(_args(calib, folder, out, "--skip-bad"))
    assert result.exit_code == 0 and "1 images skipped" in result.output, result.output
    skipped = json.loads((out / "build.json").read_text())["counts"]["skipped_images"]
    assert [s["path"] for s in skipped] == [str(bad)] and skipped[0]["problem"].startswith("corrupt JPEG")
    assert "000002.jpg" not in set(pq.read_table(out / "labels.parquet")["raw_path"].to_pylist())


def test_corrupt_jpeg_in_a_bags_compressed_image_is_named_or_skipped(small_camera, tmp_path: Path) -> None:
    pytest.importorskip("rosbags")
    calib = tmp_path / "calib_cam_to_cam.txt"
    calib.write_text(kitti_text({"02": small_camera}))
    bag = compressed_bag(tmp_path / "corrupt.bag", [raw_image(small_camera.size, i) for i in range(3)], START_NS,
                         "jpeg", {1: corrupt})
    assert_one_line_error(run_cli(_args(calib, bag, tmp_path / "stopped")), str(bag), "/cam0/image_raw",
                          f"{START_NS + 1} ns", "undecodable jpeg image: corrupt JPEG")
    out = tmp_path / "out"
    result = run_cli(_args(calib, bag, out, "--skip-bad"))
    assert result.exit_code == 0 and "1 images skipped" in result.output, result.output
    assert sorted(set(pq.read_table(out / "labels.parquet")["frame"].to_pylist())) == [0, 2]


def test_iter_images_reads_files_and_frames_by_the_builds_rules(small_camera, tmp_path: Path) -> None:
    # Every consumer of an --images spec (predict, the studies, detect, fit --online) reads through the build's
    # own reader (sources.raw.RawReader): OpenCV's pixels, grey when asked, a file cut short since it was listed
    # named in one line.
    pytest.importorskip("rosbags")
    images = [raw_image(small_camera.size, i) for i in range(3)]
    calib = tmp_path / "calib_cam_to_cam.txt"
    calib.write_text(kitti_text({"02": small_camera}))
    folder = tmp_path / "png"
    for i, image in enumerate(images):
        write_png(folder / f"{i}.png", image)
    bag = compressed_bag(tmp_path / "frames.bag", images, START_NS, "png", {})
    # Grey: a file as OpenCV reads it grey, a frame converted after decoding (the two differ by up to one level).
    greys = {folder: [cv2.imread(str(folder / f"{i}.png"), cv2.IMREAD_GRAYSCALE) for i in range(3)],
             bag: [cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) for image in images]}
    for spec in (folder, bag):
        listed = list(resolve_inputs(str(spec), str(calib)).images)
        assert all(np.array_equal(a, b) for a, b in zip(iter_images(listed), images, strict=True)), spec
        assert all(np.array_equal(a, b) for a, b in zip(iter_images(listed, 1), greys[spec], strict=True)), spec
    listed = list(resolve_inputs(str(folder), str(calib)).images)
    cut = folder / "1.png"
    cut.write_bytes(cut.read_bytes()[:-20])
    with pytest.raises(AppdgenError, match=f"^{cut}: ") as error:
        list(iter_images(listed))
    assert "\n" not in str(error.value)


def test_only_sources_decodes_raw_frames() -> None:
    package = ROOT / "appdgen"
    calls = {(str(path.relative_to(package)), node.lineno)
             for path in package.rglob("*.py") if path.relative_to(package).parts[0] != "sources"
             for node in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
             if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
             and (node.value.id, node.attr) in DECODERS}
    assert {name for name, _ in calls} <= OWN_OUTPUTS, sorted(calls)


@pytest.mark.parametrize("channels", [1, 3])
def test_the_offline_loaders_png_decoder_gives_opencvs_pixels(channels: int) -> None:
    from appdgen.dataset import shardset as data
    from appdgen.dataset.images import encode_image

    image = raw_image((348, 128), 9)
    image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if channels == 1 else image
    png = encode_image(image, ".png")
    decoded = data.decode_sample(png, "png", "shard: sample")
    assert decoded.shape == (128, 348, channels) and np.array_equal(decoded.reshape(image.shape), image)
    if data.pyspng is None:
        pytest.skip("pyspng not installed: the loader used OpenCV")
    with pytest.raises(Exception, match="shard: sample: not a readable image"):
        data.decode_sample(png[:40], "png", "shard: sample")


def test_a_missing_listed_image_says_where_relative_paths_are_read_from(tmp_path):
    """A list written with paths relative to the working folder: the one line says the list's folder is the base."""
    from appdgen.sources.files import check_images, list_images

    listing = tmp_path / "lists" / "frames.txt"
    listing.parent.mkdir()
    listing.write_text("../shared/frame.png\n")
    with pytest.raises(AppdgenError, match=r"frame\.png: cannot read image .*relative paths in a list file are "
                                           r"read from the list's folder \(use --skip-bad"):
        check_images(list_images(str(listing)), (8, 8), skip_bad=False)
