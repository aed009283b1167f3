"""The PNG encoders (`build --encoder`): fixed bytes for a fixed image (committed sha256, the same on every
machine), standard PNG read back bit for bit, recorded in build.json, checked by verify, and kept on resume."""
from __future__ import annotations

import hashlib
import json
import platform
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from appdgen.dataset.encoders import DEFAULT_ENCODER, ENCODERS, get_encoder, png_file, sub_filtered_rows
from appdgen.dataset.verify import verify
from appdgen.errors import AppdgenError
from helpers import Setup, assert_one_line_error, run_cli, run_with_full_disk, tree_digest

#: sha256 of fixed_image() encoded by each encoder (its library's version decides them: opencv 4.x's libpng and
#: zlib, fpng 0.1.0, deflate 0.9.0's libdeflate). A change here changes every build's bytes: bump only on purpose,
#: saying so.
GOLDEN = {
    "opencv": "7cb8eff2f4fdc3a4c37853b7309b9405c8d5089af0f05d99c2160e7a0f095981",
    "fpng": "6de468dde85a61b951c6c41e0b2050507799a6ebc4e165768e6520968dd9ff38",
    "libdeflate": "b72536a7968874f6beb485973bc4f160208677702f3d78f5262852747bb5282a",
}
#: sha256 of fixed_image()'s green channel as a grey image, for the encoders that write grey.
GOLDEN_GREY = {
    "opencv": "fe4477a00c895077343fc65cff0c3bf5ae83c283958ae411e2a92adb15bb3a6a",
    "libdeflate": "2bdb263d49da453684767bc5876da2b205dd154fbb082e6022545ebe90384fb6",
}


def fixed_image() -> np.ndarray:
    """An 80x48 BGR image from integer arithmetic alone (no library's rounding in it): gradients and a texture."""
    y, x = np.mgrid[0:48, 0:80]
    return np.stack([(x * 3 + y * 5 + c * 70 + (x * y) % 17) % 256 for c in range(3)], axis=2).astype(np.uint8)


def installed(name: str):
    """The encoder, or a skip when its optional package is missing here."""
    if not ENCODERS[name].available():
        pytest.skip(f"{ENCODERS[name].package} not installed (pip install 'appdgen[{ENCODERS[name].package}]')")
    return ENCODERS[name]


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_fixed_image_encodes_to_the_committed_bytes(name: str) -> None:
    data = installed(name).encode(fixed_image())
    assert hashlib.sha256(data).hexdigest() == GOLDEN[name]


@pytest.mark.parametrize("name", sorted(GOLDEN_GREY))
def test_fixed_grey_image_encodes_to_the_committed_bytes(name: str) -> None:
    grey = np.ascontiguousarray(fixed_image()[:, :, 1])
    assert hashlib.sha256(installed(name).encode(grey)).hexdigest() == GOLDEN_GREY[name]


def test_opencv_encoder_is_todays_png_level_1() -> None:
    image = fixed_image()
    today = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 1])[1].tobytes()
    assert ENCODERS["opencv"].encode(image) == today


def png_chunks(data: bytes) -> list[tuple[bytes, bytes]]:
    """(tag, data) of every chunk of a PNG file, each one's CRC checked with zlib's crc32: an independent reader."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    chunks, at = [], 8
    while at < len(data):
        (length,), tag = struct.unpack(">I", data[at:at + 4]), data[at + 4:at + 8]
        body, (crc,) = data[at + 8:at + 8 + length], struct.unpack(">I", data[at + 8 + length:at + 12 + length])
        assert crc == zlib.crc32(tag + body), tag
        chunks.append((tag, body))
        at += 12 + length
    return chunks


def sub_rows_by_hand(image: np.ndarray) -> bytes:
    """The Sub-filtered RGB scanlines, row by row in int arithmetic (the PNG spec's formula, no numpy wrapping)."""
    rgb = image[:, :, ::-1] if image.ndim == 3 else image[:, :, None]
    rows = b""
    for row in rgb.reshape(image.shape[0], -1).astype(int).tolist():
        bpp = rgb.shape[2]
        rows += bytes([1] + [(v - (row[i - bpp] if i >= bpp else 0)) % 256 for i, v in enumerate(row)])
    return rows


@pytest.mark.parametrize("shape", [(48, 80, 3), (48, 80), (7, 13, 3), (5, 1), (1, 9, 3), (1, 1), (31, 1, 3)])
def test_libdeflate_writes_sub_filtered_standard_png(shape: tuple[int, ...]) -> None:
    image = np.random.default_rng(len(shape) * 100 + shape[1]).integers(0, 256, shape, dtype=np.uint8)
    data = installed("libdeflate").encode(image)
    chunks = png_chunks(data)
    assert [tag for tag, _ in chunks] == [b"IHDR", b"IDAT", b"IEND"] and chunks[2][1] == b""
    colour = 2 if image.ndim == 3 else 0
    assert struct.unpack(">IIBBBBB", chunks[0][1]) == (shape[1], shape[0], 8, colour, 0, 0, 0)
    assert zlib.decompress(chunks[1][1]) == sub_rows_by_hand(image)
    assert np.array_equal(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED), image)


def test_png_file_frames_any_zlib_stream_for_an_independent_reader() -> None:
    rows = np.array([[0, 10, 20, 30], [0, 40, 50, 60]], np.uint8)  # filter 0 (None): the bytes are the pixels
    data = png_file(3, 2, 1, zlib.compress(rows.tobytes()))
    assert np.array_equal(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED), rows[:, 1:])
    assert png_chunks(data)[0][1] == struct.pack(">IIBBBBB", 3, 2, 8, 0, 0, 0, 0)
    assert sub_filtered_rows(rows[:, 1:]).tobytes() == bytes([1, 10, 10, 10, 1, 40, 10, 10])


def test_libdeflate_bytes_are_the_same_in_a_fresh_process() -> None:
    installed("libdeflate")
    # libdeflate picks its checksum and table set-up kernels by cpuid alone (no switch to vary here); those do not
    # change the stream (ebiggers/libdeflate#400). numpy's uint8 subtraction wraps exactly at any SIMD width and
    # BGR->RGB is a byte permutation, so neither can change the filtered rows. What can vary here is the process:
    # a fresh interpreter, one OpenCV thread, a frame big enough for libdeflate's match finder to rebase its tables.
    script = """
import hashlib, sys, cv2, numpy as np
sys.path.insert(0, sys.argv[1])
from test_encoders import street_like
from appdgen.dataset.encoders import ENCODERS
cv2.setNumThreads(1)
print(hashlib.sha256(ENCODERS["libdeflate"].encode(street_like())).hexdigest())
"""
    fresh = subprocess.run([sys.executable, "-c", script, str(Path(__file__).parent)], capture_output=True,
                           text=True, check=True).stdout.strip()
    assert fresh == hashlib.sha256(ENCODERS["libdeflate"].encode(street_like())).hexdigest()


def street_like() -> np.ndarray:
    """A 512x1392 BGR frame from integer arithmetic: smooth gradients, edges and a texture (a street's statistics)."""
    y, x = np.mgrid[0:512, 0:1392]
    return np.stack([((x // 7) * (c + 1) + (y // 5) * 3 + ((x * y) >> 9) % 23 + 40 * ((x + 2 * y) // 97 % 2)) % 256
                     for c in range(3)], axis=2).astype(np.uint8)


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_output_is_standard_png_read_back_bit_identical(name: str) -> None:
    rng = np.random.default_rng(3)
    image = cv2.GaussianBlur(rng.integers(0, 256, (64, 96, 3), dtype=np.uint8), (0, 0), 1.2)
    data = installed(name).encode(image)
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert np.array_equal(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED), image)
    spng = pytest.importorskip("pyspng")  # a second, independent PNG reader (RGB order)
    assert np.array_equal(spng.load(data)[:, :, ::-1], image)


def test_fpng_bytes_do_not_depend_on_its_sse_path(tmp_path: Path) -> None:
    installed("fpng")
    np.save(tmp_path / "rgb.npy", np.ascontiguousarray(fixed_image()[:, :, ::-1]))
    # `import fpng` calls fpng_ext.init(), which turns the SSE4.1/PCLMUL checksums on where the CPU has them;
    # loading the extension alone leaves fpng on its scalar code. Both must write the same bytes.
    script = """
import hashlib, importlib.util, glob, os, sys
import numpy as np
spec = importlib.util.find_spec("fpng")
so = glob.glob(os.path.join(os.path.dirname(spec.origin), "fpng_ext*"))[0]
ext_spec = importlib.util.spec_from_file_location("fpng.fpng_ext", so)
ext = importlib.util.module_from_spec(ext_spec)
ext_spec.loader.exec_module(ext)
if sys.argv[1] == "simd":
    ext.init()
rgb = np.load(sys.argv[2])
print(ext.cpu_supports_sse41(), hashlib.sha256(ext.encode_ndarray(rgb)).hexdigest())
"""
    runs = {path: subprocess.run([sys.executable, "-c", script, path, str(tmp_path / "rgb.npy")],
                                 capture_output=True, text=True, check=True).stdout.split()
            for path in ("scalar", "simd")}
    assert runs["scalar"] == ["False", GOLDEN["fpng"]]
    assert runs["simd"][1] == GOLDEN["fpng"]
    if platform.machine().lower() in ("x86_64", "amd64"):  # every x86-64 CPU of the last 15 years has SSE4.1
        assert runs["simd"][0] == "True", "the SSE path was not on: the comparison above checked nothing"


def test_encoder_choices_are_refused_in_one_line() -> None:
    with pytest.raises(AppdgenError, match="expected one of opencv, fpng, libdeflate"):
        get_encoder("zopfli")
    assert get_encoder(DEFAULT_ENCODER, 1) is ENCODERS["libdeflate"]
    with pytest.raises(AppdgenError, match="--encoder fpng: writes colour images only, not --channels 1"):
        get_encoder("fpng", 1) if ENCODERS["fpng"].available() else pytest.skip("fpng not installed")


def test_build_records_the_encoder_verify_checks_it_and_resume_keeps_it(setup: Setup, tmp_path: Path) -> None:
    installed("fpng")
    out = tmp_path / "out"
    result = run_cli(setup.args(out, "--encoder", "fpng"))
    assert result.exit_code == 0, result.output
    info = json.loads((out / "build.json").read_text())
    assert info["encoder"] == "fpng" and info["libraries"]["fpng"] == ENCODERS["fpng"].version()
    assert verify(out).ok
    # The shards' images are fpng's bytes: recorded as opencv, verify finds they are not OpenCV's.
    (out / "build.json").write_text(json.dumps({**info, "encoder": "opencv"}))
    problems = verify(out).problems
    assert len(problems) == setup.shard_count and all("not the bytes --encoder opencv writes" in p for p in problems)


def test_resume_with_another_encoder_is_refused_naming_the_plan(setup: Setup, interrupted_build: Path) -> None:
    installed("fpng")
    before = tree_digest(interrupted_build)
    result = run_cli(setup.args(interrupted_build, "--resume", "--encoder", "fpng"))
    assert_one_line_error(result, str(interrupted_build / ".parts" / "plan.json"),
                          f"--encoder {DEFAULT_ENCODER}, not fpng")
    assert tree_digest(interrupted_build) == before


def shard_tars(out: Path) -> dict[str, bytes]:
    """A build folder's shard tars by name: what the images' bytes are compared by."""
    return {p.name: p.read_bytes() for p in sorted(out.glob("*.tar"))}


def test_resume_without_encoder_goes_on_with_the_plans(setup: Setup, tmp_path: Path) -> None:
    # An interrupted --encoder opencv build, resumed as `--resume` alone (today's default is another encoder),
    # finishes with OpenCV's bytes: those of the same build uninterrupted.
    out, whole = tmp_path / "out", tmp_path / "whole"
    assert run_with_full_disk(setup.args(out, "--encoder", "opencv"), 6).exit_code == 2
    result = run_cli(setup.args(out, "--resume"))
    assert result.exit_code == 0, result.output
    assert run_cli(setup.args(whole, "--encoder", "opencv")).exit_code == 0
    assert json.loads((out / "build.json").read_text())["encoder"] == "opencv"
    assert shard_tars(out) and shard_tars(out) == shard_tars(whole)


@pytest.mark.parametrize("recorded", ["absent", DEFAULT_ENCODER])
def test_a_jpg_build_names_no_encoder_and_resumes_whatever_its_plan_says(setup: Setup, tmp_path: Path,
                                                                         recorded: str) -> None:
    # A jpg build has no PNG encoder: build.json says null. Its plan from before --encoder names none (read as
    # opencv for PNG) and the first --encoder version's named the default: both resume.
    out, whole = tmp_path / "out", tmp_path / "whole"
    assert run_with_full_disk(setup.args(out, "--format", "jpg"), 6).exit_code == 2
    plan_path = out / ".parts" / "plan.json"
    plan = json.loads(plan_path.read_text())
    assert plan["encoder"] is None
    if recorded == "absent":
        del plan["encoder"]
    else:
        plan["encoder"] = recorded
    plan_path.write_text(json.dumps(plan))
    result = run_cli(setup.args(out, "--format", "jpg", "--resume"))
    assert result.exit_code == 0, result.output
    assert run_cli(setup.args(whole, "--format", "jpg")).exit_code == 0
    assert json.loads((out / "build.json").read_text())["encoder"] is None
    assert shard_tars(out) and shard_tars(out) == shard_tars(whole)


def test_fpng_refuses_grey_and_non_png_builds(setup: Setup, tmp_path: Path) -> None:
    installed("fpng")
    result = run_cli(setup.args(tmp_path / "grey", "--encoder", "fpng", "--channels", "1"))
    assert_one_line_error(result, "--encoder fpng", "--channels 1")
    result = run_cli(setup.args(tmp_path / "jpg", "--encoder", "fpng", "--format", "jpg"))
    assert_one_line_error(result, "--encoder fpng", "--format png only")


def test_verify_leaves_the_encoding_unchecked_under_another_library_version(reference_build: Path,
                                                                           tmp_path: Path) -> None:
    import shutil

    out = tmp_path / "copy"
    shutil.copytree(reference_build, out)
    info = json.loads((out / "build.json").read_text())
    library, here = ENCODERS[info["encoder"]].library, ENCODERS[info["encoder"]].version()
    info["libraries"][library] = "0.0.1"
    (out / "build.json").write_text(json.dumps(info))
    report = verify(out)
    assert report.ok and report.notes == [f"build.json records {library} 0.0.1, this machine has {here}: "
                                          f"the images' encoding is unchecked (their sha256 is)"]
    assert verify(reference_build).ok and verify(reference_build).notes == []


def test_default_build_writes_libdeflates_bytes_and_opencv_keeps_todays(setup: Setup, tmp_path: Path) -> None:
    installed("libdeflate")
    default, opencv = tmp_path / "default", tmp_path / "opencv"
    assert run_cli(setup.args(default)).exit_code == 0
    assert run_cli(setup.args(opencv, "--encoder", "opencv")).exit_code == 0
    infos = [json.loads((out / "build.json").read_text()) for out in (default, opencv)]
    assert [i["encoder"] for i in infos] == ["libdeflate", "opencv"]
    assert infos[0]["libraries"]["deflate"] == ENCODERS["libdeflate"].version() and verify(default).ok
    # The same samples (labels, pixels) whatever the encoder; only the PNG bytes differ.
    rows = [pd.read_parquet(out / "labels.parquet") for out in (default, opencv)]
    assert rows[0].drop(columns="sha256").equals(rows[1].drop(columns="sha256"))
    assert not set(rows[0]["sha256"]) & set(rows[1]["sha256"])
