"""No surprises for a new user (issue #13): unreachable --appd-max refused up front, working hints, decode failures
found, resume by content, lists with spaces, --jobs as joblib, small builds on every worker, one owner per name."""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

import appdgen.sources.raw
from appdgen.calib.calibration import Calibration
from appdgen.cli import main
from appdgen.dataset.layout import FORMATS, STAGES, ShardStats
from appdgen.dataset.plan import BuildConfig, default_shard_size
from appdgen.errors import AppdgenError
from appdgen.geometry.remap import INTERPOLATIONS
from appdgen.sampling.reach import UnreachableError
from appdgen.sampling.sampler import Sampler
from appdgen.sources.files import SPLIT_BY, list_images
from appdgen.sources.frames import RawImage
from appdgen.sources.raw import read_raw
from appdgen.util.distribute import BACKENDS, resolve_jobs
from helpers import Setup, assert_one_line_error, assert_same_build, kitti_text, run_cli, run_with_full_disk

ROOT = Path(__file__).resolve().parents[1]

# --- 1. reachability before anything is written ------------------------------------------------------------------


def test_a_zero_distortion_camera_with_unreachable_appd_max_is_refused_up_front(tmp_path: Path) -> None:
    # As a new user on ApolloScape-like frames: 3384x2710, D = 0, absolute distortion ranges, default --appd-max 1.
    camera = Calibration(3384, 2710, 2304.5, 2305.9, 1686.2, 1354.98)
    (tmp_path / "calib.txt").write_text(kitti_text({"05": camera}))
    (tmp_path / "raw").mkdir()
    cv2.imwrite(str(tmp_path / "raw" / "a.png"), np.zeros((2710, 3384, 3), np.uint8))
    out = tmp_path / "out"
    result = run_cli(["build", "--calib", str(tmp_path / "calib.txt"), "--images", str(tmp_path / "raw"), "--out",
                      str(out), "--ranges", "fx=-5%:5%,cx=-5%:5%,k1=-0.03:0.03", "--size", "423x339", "--quiet"])
    line = assert_one_line_error(result, "--appd-max 1", "lower --appd-max or widen --ranges",
                                 "without lens distortion")
    assert 0.3 < float(re.search(r"about ([\d.]+) %", line).group(1)) < 1.0
    assert not out.exists()


def test_a_mid_build_refusal_of_the_ranges_says_to_overwrite(setup: Setup, tmp_path: Path, monkeypatch) -> None:
    def unreachable(self, seed: int, index: int):
        raise UnreachableError("--appd-max 1: after 200 directions none reached APPD 0.999 % inside the ranges; "
                               "lower --appd-max or widen --ranges")

    monkeypatch.setattr(Sampler, "draw", unreachable)
    line = assert_one_line_error(run_cli(setup.args(tmp_path / "out")), "lower --appd-max or widen --ranges")
    assert "rebuild with --overwrite" in line and "rerun with --resume" not in line


# --- 3. decode failures ------------------------------------------------------------------------------------------


def _jpeg(path: Path, size: tuple[int, int], seed: int = 0) -> Path:
    """A textured JPEG of `size`."""
    image = cv2.GaussianBlur(np.random.default_rng(seed).integers(0, 256, (size[1], size[0], 3), np.uint8), (0, 0), 2)
    assert cv2.imwrite(str(path), image)
    return path


@pytest.fixture
def jpeg_inputs(setup: Setup, tmp_path: Path, small_camera: Calibration) -> tuple[Path, Path]:
    """Two good JPEGs and one cut in half (header intact: OpenCV decodes it, the lower half grey)."""
    folder = tmp_path / "jpegs"
    folder.mkdir()
    for i in range(3):
        _jpeg(folder / f"{i}.jpg", small_camera.size, i)
    cut = folder / "1.jpg"
    cut.write_bytes(cut.read_bytes()[: cut.stat().st_size // 2])
    assert cv2.imread(str(cut)) is not None  # the silent grey sample this guards against
    return folder, cut


def test_a_truncated_jpeg_is_an_error_naming_it(setup: Setup, jpeg_inputs: tuple[Path, Path], tmp_path: Path) -> None:
    folder, cut = jpeg_inputs
    args = Setup(setup.calib, folder, samples=6, shard_size=2).args(tmp_path / "out")
    assert_one_line_error(run_cli(args), str(cut), "truncated JPEG", "--skip-bad")
    assert not (tmp_path / "out").exists()


def test_skip_bad_skips_a_truncated_image_and_lists_it(setup: Setup, jpeg_inputs: tuple[Path, Path],
                                                       tmp_path: Path) -> None:
    folder, cut = jpeg_inputs
    result = run_cli(Setup(setup.calib, folder, samples=6, shard_size=2).args(tmp_path / "out", "--skip-bad"))
    assert result.exit_code == 0, result.output
    info = json.loads((tmp_path / "out" / "build.json").read_text())
    assert info["counts"]["images"] == 2
    [skipped] = info["counts"]["skipped_images"]
    assert skipped["path"] == str(cut) and skipped["problem"].startswith("truncated JPEG")
    assert [name for name, _ in info["images"]] == ["0.jpg", "2.jpg"]


def test_an_image_cut_after_the_check_fails_in_the_worker(tmp_path: Path, small_camera: Calibration) -> None:
    path = _jpeg(tmp_path / "a.jpg", small_camera.size)
    assert read_raw(path).shape == (small_camera.height, small_camera.width, 3)
    path.write_bytes(path.read_bytes()[:-400])
    with pytest.raises(AppdgenError, match="a.jpg: truncated JPEG"):
        read_raw(path)


def test_an_image_with_alpha_is_refused(setup: Setup, tmp_path: Path, small_camera: Calibration) -> None:
    folder = tmp_path / "rgba"
    folder.mkdir()
    cv2.imwrite(str(folder / "a.png"), np.full((small_camera.height, small_camera.width, 4), 200, np.uint8))
    args = Setup(setup.calib, folder, samples=2, shard_size=2).args(tmp_path / "out")
    assert_one_line_error(run_cli(args), "a.png", "has 4 channels")


# --- 4. resume by content ----------------------------------------------------------------------------------------


def test_resume_from_another_folder_through_relative_paths(setup: Setup, interrupted_build: Path,
                                                           reference_build: Path, tmp_path: Path,
                                                           monkeypatch) -> None:
    out = Path(shutil.copytree(interrupted_build, tmp_path / "out"))
    monkeypatch.chdir(setup.calib.parent)
    relative = Setup(Path(setup.calib.name), Path(setup.images.name))
    result = run_cli(relative.args(Path(os.path.relpath(out)), "--resume"))
    assert result.exit_code == 0, result.output
    assert_same_build(out, reference_build)


def test_resume_refuses_a_calibration_file_that_changed(setup: Setup, tmp_path: Path) -> None:
    calib = tmp_path / "calib_cam_to_cam.txt"
    shutil.copy(setup.calib, calib)
    changed = Setup(calib, setup.images)
    out = tmp_path / "out"
    assert run_with_full_disk(changed.args(out), 6).exit_code == 2  # interrupted after two shards
    calib.write_text(calib.read_text() + "note: recalibrated on a later day\n")
    assert_one_line_error(run_cli(changed.args(out, "--resume")), "other inputs or options",
                          "calibration file or image set that changed")


# --- 5. lists and --jobs -----------------------------------------------------------------------------------------


def test_a_tab_separated_list_holds_paths_with_spaces(setup: Setup, tmp_path: Path) -> None:
    folder = tmp_path / "drive one"
    folder.mkdir()
    sources = sorted(setup.images.iterdir())
    for i, source in enumerate(sources[:2]):
        shutil.copy(source, folder / f"frame #{i} .png")
    listing = tmp_path / "list.txt"
    listing.write_text(f"drive one/frame #0 .png\ttrain\n# a comment\n{folder}/frame #1 .png\t val \n")
    assert [(i.name, i.split) for i in list_images(str(listing))] == [
        ("drive one/frame #0 .png", "train"), (f"{folder}/frame #1 .png", "val")]
    result = run_cli(Setup(setup.calib, listing, samples=4, shard_size=2).args(tmp_path / "out"))
    assert result.exit_code == 0, result.output


def test_jobs_follow_joblib(setup: Setup, reference_build: Path, tmp_path: Path) -> None:
    cores = resolve_jobs(None)
    assert resolve_jobs(-1) == cores and resolve_jobs(-2) == max(cores - 1, 1) and resolve_jobs(3) == 3
    assert resolve_jobs(-10_000) == 1
    with pytest.raises(AppdgenError, match="--jobs 0.*-1 for all cores"):
        resolve_jobs(0)
    result = run_cli(setup.args(tmp_path / "out", jobs=-1))
    assert result.exit_code == 0, result.output
    assert_same_build(tmp_path / "out", reference_build)


# --- 6. small builds use every worker ----------------------------------------------------------------------------


def test_the_default_shard_size_gives_small_builds_many_shards(small_camera: Calibration, tmp_path: Path) -> None:
    assert [default_shard_size(n) for n in (1, 24, 40, 120, 2000, 64_000, 10**6)] == [1, 8, 10, 10, 32, 1000, 1000]
    image = RawImage(tmp_path / "a.png", "a.png", "all")
    config = BuildConfig(small_camera, "02", "calib.txt", (image,), 120, (87, 32))
    assert config.shard_count == 12 and {len(config.shard_samples(k)) for k in range(12)} == {10}  # 6 per worker of 2


def test_a_build_without_shard_size_is_the_same_for_any_jobs(setup: Setup, tmp_path: Path) -> None:
    for jobs in (1, 2):
        args = setup.args(tmp_path / f"out{jobs}", jobs=jobs)
        del args[args.index("--shard-size"):args.index("--shard-size") + 2]
        assert run_cli(args).exit_code == 0
    assert len(list((tmp_path / "out1").glob("shard-*.tar"))) == 4  # 40 samples: 4 shards of 10
    assert_same_build(tmp_path / "out2", tmp_path / "out1")


# --- 7. one owner per name ---------------------------------------------------------------------------------------

OWNED = {'"labels.parquet"': "layout.py", '"build.json"': "layout.py", '"plan.json"': "layout.py",
         '"shard-': "layout.py", '.tar"': "layout.py", '".parts"': "layout.py", '"npy": ".npy"': "layout.py",
         '".npy"': "layout.py", "IMAGE_EXTS": None}
LAYOUT = ROOT / "appdgen" / "dataset"


def test_output_names_are_written_in_one_module_only() -> None:
    # The generator, the trainer and the benchmarks: each output name is spelled in layout.py alone.
    sources = [p for folder in ("appdgen", "train", "benchmarks", "studies") for p in (ROOT / folder).rglob("*.py")]
    assert LAYOUT / "layout.py" in sources and len(sources) > 50
    for literal, owner in OWNED.items():
        users = sorted(p.relative_to(LAYOUT).as_posix() if p.parent == LAYOUT else p.relative_to(ROOT).as_posix()
                       for p in sources if literal in p.read_text(encoding="utf-8"))
        assert users == ([owner] if owner else []), (literal, users)


def test_cli_choices_come_from_their_owners() -> None:
    options = {o.name: o for o in main.commands["build"].params}
    assert list(options["image_format"].type.choices) == list(FORMATS)
    assert list(options["interp"].type.choices) == list(INTERPOLATIONS)
    assert list(options["split_by"].type.choices) == list(SPLIT_BY)
    assert list(options["backend"].type.choices) == list(BACKENDS)


def test_shard_stats_are_a_typed_record() -> None:
    stats = ShardStats(shard=3, file="shard-000003.tar", samples=2, bytes=1024, splits={"train": 2}, references=0,
                       evaluations=7, stage_seconds=dict.fromkeys(STAGES, 0.1), seconds=0.5)
    assert ShardStats.from_json(stats.to_json()) == stats
    assert stats.listing() == {"file": "shard-000003.tar", "samples": 2, "bytes": 1024, "splits": {"train": 2}}


def test_architecture_names_the_modules_that_exist() -> None:
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    named = set(re.findall(r"`?\b([a-z_]+)\.py\b", text)) | set(re.findall(r"(?<![.\w])([a-z_]+)/`", text))
    packages = [ROOT / "appdgen", ROOT / "train", ROOT / "benchmarks", ROOT / "studies", ROOT / "tests"]
    missing = [n for n in sorted(named) if not any(list(p.rglob(f"{n}.py")) for p in packages)
               and not any((root / n).is_dir() for root in (ROOT / "appdgen", ROOT / "train", ROOT))]
    assert not missing, missing
    for module in ("layout", "sampler", "build", "reader", "inspect", "verify", "files", "recordings", "shards",
                   "formats",
                   "crop", "loop", "holdout"):
        assert f"{module}.py" in text, module


# --- 8. make test-core -------------------------------------------------------------------------------------------


def test_make_test_core_runs_the_suite_without_torch() -> None:
    if shutil.which("make") is None:
        pytest.skip("no make here")
    done = subprocess.run(["make", "-n", "-B", "test-core"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert "pytest" in done.stdout and "torch" not in done.stdout and "train" not in done.stdout


# --- 9. speed without changing bytes -----------------------------------------------------------------------------


@pytest.mark.parametrize("interp", list(INTERPOLATIONS))
def test_remap_gives_the_bytes_of_opencvs_float_maps(interp: str, small_camera: Calibration) -> None:
    from appdgen.geometry.maps import rectify
    from appdgen.geometry.remap import remap_image

    raw = cv2.GaussianBlur(np.random.default_rng(0).integers(0, 256, (64, 174, 3), np.uint8), (0, 0), 1.0)
    rect = rectify(small_camera.perturb(fx=0.07, k1=0.1), (87, 32))
    expected = cv2.remap(raw, rect.map_x, rect.map_y, INTERPOLATIONS[interp], borderMode=cv2.BORDER_REFLECT_101)
    assert np.array_equal(remap_image(raw, rect, interp), expected)


def test_an_image_that_fails_in_a_worker_gets_a_hint_that_works(setup: Setup, tmp_path: Path,
                                                                 monkeypatch) -> None:
    def broken(path: Path, *_) -> np.ndarray:
        raise AppdgenError(f"{path}: not a readable image")

    monkeypatch.setattr(appdgen.sources.raw, "read_image", broken)
    appdgen.sources.raw.forget_decoded()
    line = assert_one_line_error(run_cli(setup.args(tmp_path / "out")), "not a readable image")
    assert "replace the file and rerun with --resume" in line and "rebuild with --overwrite" in line
    appdgen.sources.raw.forget_decoded()
