"""The PNG encoders (`build --encoder`): fixed bytes for a fixed image (committed sha256, the same on every
machine), standard PNG read back bit for bit, recorded in build.json, checked by verify, and kept on resume."""
from __future__ import annotations

import hashlib
import json
import platform
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from appdgen.dataset.encoders import DEFAULT_ENCODER, ENCODERS, get_encoder
from appdgen.dataset.verify import verify
from appdgen.errors import AppdgenError
from helpers import Setup, assert_one_line_error, run_cli, tree_digest

#: sha256 of fixed_image() encoded by each encoder (its library's version decides them: opencv 4.x's libpng and
#: zlib, fpng 0.1.0). A change here changes every build's bytes: bump only on purpose, saying so.
GOLDEN = {
    "opencv": "7cb8eff2f4fdc3a4c37853b7309b9405c8d5089af0f05d99c2160e7a0f095981",
    "fpng": "6de468dde85a61b951c6c41e0b2050507799a6ebc4e165768e6520968dd9ff38",
}
GOLDEN_GREY_OPENCV = "fe4477a00c895077343fc65cff0c3bf5ae83c283958ae411e2a92adb15bb3a6a"


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


def test_opencv_encoder_is_todays_png_level_1() -> None:
    image = fixed_image()
    today = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 1])[1].tobytes()
    assert ENCODERS["opencv"].encode(image) == today
    grey = np.ascontiguousarray(image[:, :, 1])
    assert hashlib.sha256(ENCODERS["opencv"].encode(grey)).hexdigest() == GOLDEN_GREY_OPENCV


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
    with pytest.raises(AppdgenError, match="expected one of opencv, fpng"):
        get_encoder("zopfli")
    assert get_encoder(DEFAULT_ENCODER, 1) is ENCODERS["opencv"]
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
    assert_one_line_error(result, str(interrupted_build / ".parts" / "plan.json"), "--encoder opencv, not fpng")
    assert tree_digest(interrupted_build) == before


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
    info["libraries"]["opencv"] = "3.4.0"
    (out / "build.json").write_text(json.dumps(info))
    report = verify(out)
    assert report.ok and report.notes == [f"build.json records opencv 3.4.0, this machine has {cv2.__version__}: "
                                          f"the images' encoding is unchecked (their sha256 is)"]
    assert verify(reference_build).ok and verify(reference_build).notes == []
