"""Reliability (issue #8): bad input fails in one line and changes nothing; kills, full disks, tar safety, Dask."""
from __future__ import annotations

import os
import random
import shutil
import subprocess
import tarfile
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from appdgen.calib.calibration import PARAMS
from appdgen.errors import AppdgenError
from appdgen.sampling.ranges import parse_ranges
from appdgen.sources.files import SPLIT_BY, _read_list, list_images
from helpers import (
    Setup,
    assert_killed_build_sound,
    assert_one_line_error,
    assert_same_build,
    assert_shard_complete,
    kill_group,
    run_cli,
    run_with_full_disk,
    spawn_cli,
    tree_digest,
)

BAD = Path(__file__).parent / "data" / "bad"
BASE = {"--calib": "ok_calib.txt", "--images": "ok_images", "--samples": "4", "--shard-size": "2", "--size": "87x32",
        "--jobs": "1"}
IN_BAD = ("--calib", "--images")  # options whose values are paths under tests/data/bad
ALL_ZERO = ",".join(f"{name}=0:0" for name in PARAMS)

CASES = [  # id, options changed from BASE (None drops one, "" is a flag), fragments of the one-line message
    ("calib-truncated", {"--calib": "calib_truncated.txt"}, ["calib_truncated.txt", "K_02: expected 9 numbers"]),
    ("calib-missing-camera", {"--calib": "calib_missing_camera.txt", "--camera": "02"},
     ["calib_missing_camera.txt", "camera '02' not found; available: 00, 01"]),
    ("calib-missing-key", {"--calib": "calib_missing_key.txt"}, ["calib_missing_key.txt", "missing key D_02"]),
    ("calib-nan", {"--calib": "calib_nan.txt"}, ["calib_nan.txt", "K_02[0]: expected a finite number"]),
    ("calib-inf", {"--calib": "calib_inf.txt"}, ["calib_inf.txt", "D_02[1]: expected a finite number"]),
    ("calib-negative-focal", {"--calib": "calib_negative_focal.txt"},
     ["calib_negative_focal.txt", "focal lengths must be positive"]),
    ("calib-wrong-matrix-shape", {"--calib": "calib_wrong_shape.yaml"},
     ["calib_wrong_shape.yaml", "camera matrix: expected 3x3, got 2x3"]),
    ("calib-fold-over", {"--calib": "calib_foldover.txt"}, ["calib_foldover.txt", "distortion folds over"]),
    ("calib-far-principal-point", {"--calib": "calib_far_principal_point.txt"},
     ["calib_far_principal_point.txt", "camera 02: "]),
    ("calib-unknown-format", {"--calib": "calib_unknown.yaml"}, ["calib_unknown.yaml", "unknown calibration format"]),
    ("calib-binary-garbage", {"--calib": "calib_garbage.bin"}, ["calib_garbage.bin", "binary data"]),
    ("calib-empty", {"--calib": "calib_empty.txt"}, ["calib_empty.txt", "empty file"]),
    ("calib-not-utf8", {"--calib": "calib_latin1.txt"}, ["calib_latin1.txt", "not UTF-8"]),
    ("calib-missing-file", {"--calib": "absent.txt"}, ["absent.txt", "no such file"]),
    ("calib-is-a-folder", {"--calib": "ok_images"}, ["--calib", "is a directory"]),
    ("calib-other-size", {"--calib": "calib_wrong_size.txt", "--camera": "02"},
     ["a.png", "is 174x64, the calibration 348x128"]),
    ("calib-no-camera-fits", {"--calib": "calib_wrong_size.txt"},
     ["calib_wrong_size.txt", "no camera (00, 02) is 174x64 like"]),
    ("images-missing-file", {"--images": "list_missing_file.txt"}, ["missing.png", "No such file"]),
    ("images-unreadable", {"--images": "images_garbage"}, ["a.png", "not a readable image"]),
    ("images-truncated", {"--images": "images_truncated"}, ["a.png", "truncated PNG"]),
    ("images-wrong-size", {"--images": "images_wrong_size"}, ["c.png", "is 100x37, the calibration 174x64"]),
    ("images-empty-folder", {"--images": "images_none"}, ["images_none", "folder has no images"]),
    ("images-duplicate", {"--images": "list_duplicate.txt"}, ["list_duplicate.txt", "a.png is listed twice"]),
    ("images-bad-list-line", {"--images": "list_bad_line.txt"}, ["list_bad_line.txt:1", "expected 'PATH [SPLIT]'"]),
    ("images-list-names-none", {"--images": "list_comments_only.txt"}, ["list_comments_only.txt", "names no images"]),
    ("images-list-garbage", {"--images": "list_garbage.txt"}, ["list_garbage.txt", "cannot read image list"]),
    ("images-list-names-folder", {"--images": "list_folder.txt"}, ["ok_images", "Is a directory"]),
    ("images-absent", {"--images": "absent"}, ["absent", "no such folder, list file or glob pattern"]),
    ("images-glob-matches-none", {"--images": "ok_images/*.jpg"}, ["*.jpg", "pattern matches no images"]),
    ("size-not-wxh", {"--size": "87"}, ["--size '87'", "expected WIDTHxHEIGHT"]),
    ("size-zero", {"--size": "0x0"}, ["--size '0x0'", "must be positive"]),
    ("size-other-aspect", {"--size": "100x100"}, ["--size", "raw aspect 174:64"]),
    ("ranges-empty", {"--ranges": ALL_ZERO}, ["--ranges", "every range is empty"]),
    ("ranges-reversed", {"--ranges": "fx=20%:-5%"}, ["--ranges 'fx=20%:-5%'", "LOW <= 0 <= HIGH"]),
    ("ranges-malformed", {"--ranges": "fx=1"}, ["--ranges 'fx=1'", "expected NAME=LOW:HIGH"]),
    ("ranges-mixed-units", {"--ranges": "k1=-1%:0.1"}, ["--ranges 'k1=-1%:0.1'", "both bounds in %"]),
    ("samples-zero", {"--samples": "0"}, ["--samples 0", "at least 1"]),
    ("samples-not-a-number", {"--samples": "many"}, ["--samples", "not a valid integer"]),
    ("per-image-zero", {"--samples": None, "--per-image": "0"}, ["--per-image 0", "at least 1"]),
    ("samples-and-per-image", {"--per-image": "2"}, ["--samples or --per-image"]),
    ("shard-size-zero", {"--shard-size": "0"}, ["--shard-size 0", "at least 1"]),
    ("jobs-zero", {"--jobs": "0"}, ["--jobs 0", "-1 for all cores"]),
    ("appd-max-zero", {"--appd-max": "0"}, ["--appd-max 0", "must be a positive number"]),
    ("appd-max-nan", {"--appd-max": "nan"}, ["--appd-max nan", "must be a positive number"]),
    ("zero-fraction-above-one", {"--zero-fraction": "1.5"}, ["--zero-fraction 1.5", "must be in [0, 1]"]),
    ("format-unknown", {"--format": "gif"}, ["--format", "'gif' is not one of"]),
    ("camera-absent", {"--camera": "7"}, ["ok_calib.txt", "camera '7' not found"]),
    ("resume-and-overwrite", {"--resume": "", "--overwrite": ""}, ["--resume or --overwrite, not both"]),
]


def _args(changes: dict[str, str | None], out: Path) -> list[str]:
    """`appdgen build` arguments: BASE with changes, paths resolved under tests/data/bad, into `out`."""
    args = ["build", "--out", str(out), "--quiet"]
    for option, value in {**BASE, **changes}.items():
        if value is not None:
            args += [option] if value == "" else [option, str(BAD / value) if option in IN_BAD else value]
    return args


@pytest.mark.parametrize(("changes", "fragments"), [pytest.param(c, f, id=n) for n, c, f in CASES])
def test_bad_input_fails_in_one_line_and_changes_nothing(changes: dict, fragments: list[str], tmp_path: Path,
                                                         reference_build: Path, capfd: pytest.CaptureFixture) -> None:
    absent = tmp_path / "absent"
    assert_one_line_error(run_cli(_args(changes, absent)), *fragments)
    assert not absent.exists()
    finished = tmp_path / "finished"
    shutil.copytree(reference_build, finished)
    before = tree_digest(finished)
    assert_one_line_error(run_cli(_args({**changes, "--overwrite": ""}, finished)), *fragments)
    assert tree_digest(finished) == before
    assert capfd.readouterr() == ("", "")  # nothing written past click (C libraries' warnings, say)


def test_corpus_is_big_and_every_file_is_used() -> None:
    assert len(CASES) >= 20 and len({name for name, _, _ in CASES}) == len(CASES)
    used = {Path(v).parts[0] for _, changes, _ in CASES for o, v in changes.items() if o in IN_BAD and v}
    assert {p.name for p in BAD.iterdir()} - used - {"ok_calib.txt"} == set()


@pytest.mark.parametrize("where", ["file", "inside-a-file"])
def test_out_that_is_or_lies_in_a_file_is_refused_untouched(where: str, tmp_path: Path) -> None:
    blocker = tmp_path / "blocker"
    blocker.write_bytes(b"not a folder")
    out = blocker if where == "file" else blocker / "out"
    problem = ["'--out'", "is a file"] if where == "file" else [f"--out {out}", "cannot write (Not a directory)"]
    assert_one_line_error(run_cli(_args({}, out)), str(out), *problem)
    assert blocker.read_bytes() == b"not a folder" and sorted(tmp_path.iterdir()) == [blocker]


@pytest.fixture
def unwritable(tmp_path: Path) -> Iterator[Path]:
    """A folder this process cannot create entries in: a read-only folder, or /sys (sysfs) for root."""
    folder = tmp_path / "locked"
    folder.mkdir(mode=0o555)
    try:
        (folder / "probe").mkdir()
    except PermissionError:
        yield folder
        folder.chmod(0o755)
        return
    folder.chmod(0o755)
    probe = Path("/sys") / "appdgen-probe"
    try:
        probe.mkdir()
    except OSError:
        yield probe.parent
        return
    probe.rmdir()
    pytest.skip("no folder here refuses this process's writes (root, and /sys is writable)")


def test_out_without_write_permission_fails_in_one_line(unwritable: Path) -> None:
    out = unwritable / "out"
    before = tree_digest(unwritable) if unwritable != Path("/sys") else None
    assert_one_line_error(run_cli(_args({}, out)), f"--out {out}", "cannot write")
    assert not out.exists() and (before is None or tree_digest(unwritable) == before)


@pytest.mark.skipif(os.geteuid() == 0, reason="permission bits do not stop root")
def test_overwrite_without_write_permission_leaves_the_build(reference_build: Path, tmp_path: Path) -> None:
    finished = tmp_path / "finished"
    shutil.copytree(reference_build, finished)
    before = tree_digest(finished)
    finished.chmod(0o555)
    try:
        result = run_cli(_args({"--overwrite": ""}, finished))
    finally:
        finished.chmod(0o755)
    assert_one_line_error(result, f"--out {finished}", "cannot write")
    assert tree_digest(finished) == before


# --- fuzzing: only AppdgenError escapes -------------------------------------------------------------------------

LIST_TOKENS = ["a.png", "ok_images/a.png", "/abs/b.jpg", "../c.PNG", "train", "val", "#", " ", "\t", "\n", "\r\n",
               "\x00", "\x0b", "\x1c", "\u2028", "é", "..", "*", "[", "~", "2011_09_26_drive_0001_sync", "image_02"]
RANGE_TOKENS = ["fx", "fy", "k3", "p1", "zz", "=", ":", ",", "%", "-", "5", "0", "0.5", "1e999", "nan", "inf", " ",
                "-5%", "20%", "1_0", "\x00", "%%"]


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


@settings(max_examples=150, deadline=None, database=None)
@given(st.lists(st.sampled_from(LIST_TOKENS), max_size=30).map("".join) | st.text(max_size=200),
       st.sampled_from(SPLIT_BY))
def test_fuzz_image_lists(fuzz_dir: Path, text: str, split_by: str) -> None:
    path = fuzz_dir / "list.txt"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    for read in (lambda: _read_list(path, split_by), lambda: list_images(str(path), split_by)):
        try:
            images = read()
        except AppdgenError as exc:
            assert str(exc) and "\n" not in str(exc)
        else:
            assert all(image.name and image.split for image in images)


@settings(max_examples=300, deadline=None, database=None)
@given(st.lists(st.sampled_from(RANGE_TOKENS), max_size=14).map("".join) | st.text(max_size=60))
def test_fuzz_parse_ranges(text: str) -> None:
    try:
        ranges = parse_ranges(text)
    except AppdgenError as exc:
        assert str(exc).startswith("--ranges") and "\n" not in str(exc)
    else:
        assert all(r.low <= 0 <= r.high for r in ranges.values())


# --- kills and a full disk --------------------------------------------------------------------------------------


def _kill_at(args: list[str], moment: float, log: Path) -> bool:
    """Run `appdgen ARGS` in a subprocess and SIGKILL its group after `moment` seconds; whether it still ran."""
    process = spawn_cli(args, log)
    try:
        process.wait(timeout=moment)
        return False
    except subprocess.TimeoutExpired:
        return True
    finally:
        kill_group(process)


def _moment_reached(path: Path, process: subprocess.Popen) -> float:
    """Poll until `path` exists (or the process ends); the monotonic time then."""
    while not path.exists() and process.poll() is None:
        time.sleep(0.005)
    return time.monotonic()


def _phases(args: list[str], out: Path, log: Path) -> tuple[float, float]:
    """Run a build to its end: (seconds until its plan is written, seconds from then until build.json is)."""
    start = time.monotonic()
    process = spawn_cli(args, log)
    try:
        planned = _moment_reached(out / ".parts" / "plan.json", process)
        done = _moment_reached(out / "build.json", process)
        assert process.wait(timeout=600) == 0, log.read_text()
    finally:
        kill_group(process)
    return planned - start, done - planned


@pytest.fixture(scope="module")
def long_setup(setup: Setup) -> Setup:
    """The standard inputs with 120 samples in 15 shards: long enough for kills to land mid-build."""
    return Setup(setup.calib, setup.images, samples=120, shard_size=8)


@pytest.mark.slow
def test_random_kills_then_resume_give_identical_bytes(long_setup: Setup, tmp_path: Path) -> None:
    reference = tmp_path / "reference"
    assert run_cli(long_setup.args(reference)).exit_code == 0
    phases = {}
    for jobs in (1, 2):
        timed = tmp_path / f"timed{jobs}"
        phases[jobs] = _phases(long_setup.args(timed, jobs=jobs), timed, tmp_path / "timed.log")
        assert_same_build(timed, reference)
    rng, interrupted = random.Random(20200601), 0
    for cycle in range(12):  # some kills land before the plan or after the end: go on until 5 landed mid-build
        if interrupted >= 5:
            break
        out, jobs = tmp_path / f"cycle{cycle}", 1 + cycle % 2
        startup, work = phases[jobs]
        for args in (long_setup.args(out, jobs=jobs), long_setup.args(out, "--resume", jobs=jobs)):  # kill a resume too
            killed = _kill_at(args, rng.uniform(0.5 * startup, startup + work), tmp_path / "kill.log")
            interrupted += (out / ".parts" / "plan.json").is_file()  # .parts goes when a build ends
            assert_killed_build_sound(out, long_setup)
            if not killed:
                break
        result = run_cli(long_setup.args(out, "--resume"))
        assert result.exit_code == 0 or "already complete" in result.stderr, result.output
        assert_same_build(out, reference)
    assert interrupted >= 5, f"only {interrupted} of the kills landed mid-build"


def _plant_temporaries(out: Path) -> None:
    """What a kill during atomic writes leaves: hidden, partly written temporaries beside their targets."""
    (out / ".shard-000002.tar.0123abcd.tmp").write_bytes(b"partial tar")
    (out / ".parts" / ".shard-000002.tar.parquet.89abcdef.tmp").write_bytes(b"partial fragment")


@pytest.mark.parametrize("flag", ["--resume", "--overwrite"])
def test_temporaries_left_by_a_kill_go_on_resume_and_overwrite(setup: Setup, reference_build: Path,
                                                                interrupted_build: Path, tmp_path: Path,
                                                                flag: str) -> None:
    out = tmp_path / "out"
    shutil.copytree(interrupted_build, out)
    _plant_temporaries(out)
    assert run_cli(setup.args(out, flag)).exit_code == 0
    assert_same_build(out, reference_build)


def test_resuming_a_complete_build_clears_the_parts_a_kill_at_its_very_end_left(setup: Setup, reference_build: Path,
                                                                                 tmp_path: Path) -> None:
    out = tmp_path / "out"
    shutil.copytree(reference_build, out)
    trash = out / "..parts.0123abcd.tmp"  # BuildWriter.finish renames .parts so, then removes it
    trash.mkdir()
    (trash / "plan.json").write_text("{}")
    result = run_cli(setup.args(out, "--resume"))
    assert result.exit_code != 0 and "already complete" in result.stderr
    assert not trash.exists()
    assert_same_build(out, reference_build)


@pytest.mark.parametrize("flags", [[], ["--resume"]])
def test_a_build_killed_before_its_plan_starts_afresh(setup: Setup, reference_build: Path, tmp_path: Path,
                                                      flags: list[str]) -> None:
    out = tmp_path / "out"
    (out / ".parts").mkdir(parents=True)
    (out / ".parts" / ".plan.json.0123abcd.tmp").write_bytes(b"{")
    assert run_cli(setup.args(out, *flags)).exit_code == 0
    assert_same_build(out, reference_build)


WRITES = 1 + 2 * 5 + 2  # plan.json, (tar, fragment with its stats) per shard, labels.parquet, build.json


@pytest.mark.parametrize("fail_at", [1, 2, 3, 4, 9, WRITES - 1, WRITES])
def test_full_disk_fails_cleanly_then_resumes_to_identical_bytes(setup: Setup, reference_build: Path,
                                                                 tmp_path: Path, fail_at: int) -> None:
    out = tmp_path / "out"
    line = assert_one_line_error(run_with_full_disk(setup.args(out), fail_at), f"--out {out}",
                                 "No space left on device")
    assert fail_at == 1 or "rerun with --resume" in line
    assert_killed_build_sound(out, setup)
    assert not [p for p in out.rglob("*.tmp")], "a temporary file was left behind"
    result = run_cli(setup.args(out, "--resume"))
    assert result.exit_code == 0, result.output
    assert_same_build(out, reference_build)


# --- tar safety and Dask ----------------------------------------------------------------------------------------


def test_shard_members_are_plain_files_with_safe_names(reference_build: Path, setup: Setup) -> None:
    safe = getattr(tarfile, "data_filter", None)  # the stdlib's safe-extraction rules (3.10.12+, 3.11.4+)
    for shard in sorted(reference_build.glob("shard-*.tar")):
        # plain files named <key>.json / <key>.png: no links, '..', '/' or absolute names
        assert_shard_complete(shard, setup)
        with tarfile.open(shard) as tar:
            for member in tar.getmembers():
                assert (member.mode, member.uid, member.gid, member.mtime) == (0o644, 0, 0, 0)
                assert safe is None or safe(member, str(reference_build)) is not None


def test_dask_cluster_writes_the_same_bytes_as_loky(setup: Setup, loky_build: Path, tmp_path: Path) -> None:
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        result = run_cli(setup.args(tmp_path / "out", "--backend", "dask", "--scheduler", cluster.scheduler_address))
    assert result.exit_code == 0 and result.stderr == "", result.output
    assert_same_build(tmp_path / "out", loky_build)
