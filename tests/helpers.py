"""Test helpers: a small KITTI-like camera on disk, tiny raw images, CLI runners, shard checks, folder digests."""
from __future__ import annotations

import errno
import hashlib
import importlib.util
import io
import json
import os
import signal
import subprocess
import sys
import tarfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner, Result

import appdgen.util.atomic
from appdgen.calib.calibration import Calibration
from appdgen.cli import main
from appdgen.dataset.layout import member_record
from appdgen.geometry.crop import valid_region
from appdgen.sampling.sampler import Sampler


def load_script(name: str):
    """Import benchmarks/NAME.py as a module (benchmarks/ is not a package)."""
    spec = importlib.util.spec_from_file_location(name, Path(__file__).parents[1] / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def scaled(calib: Calibration, factor: int) -> Calibration:
    """A camera `factor` times smaller: size and K divided, distortion kept (so the crop costs the same)."""
    return Calibration(calib.width // factor, calib.height // factor, calib.fx / factor, calib.fy / factor,
                       calib.cx / factor, calib.cy / factor, calib.k1, calib.k2, calib.p1, calib.p2, calib.k3)


def kitti_text(cameras: dict[str, Calibration]) -> str:
    """A calib_cam_to_cam.txt holding S_xx, K_xx and D_xx lines (exact float reprs) for each camera."""
    lines = ["calib_time: 09-Jan-2012 13:57:47", "corner_dist: 9.950000e-02"]
    for name, c in cameras.items():
        numbers = {"S": [c.width, c.height], "K": c.K.ravel().tolist(), "D": c.D.tolist()}
        lines += [f"{key}_{name}: {' '.join(repr(float(v)) for v in values)}" for key, values in numbers.items()]
    return "\n".join(lines) + "\n"


def raw_image(size: tuple[int, int], seed: int) -> np.ndarray:
    """Blurred noise, so rectified samples differ visibly between calibrations (8-bit BGR)."""
    noise = np.random.default_rng(seed).integers(0, 256, (size[1], size[0], 3), dtype=np.uint8)
    return cv2.GaussianBlur(noise, (0, 0), 1.5)


def compressed_bag(path: Path, images: list[np.ndarray], start_ns: int, compressed: str,
                   damage: dict[int, Callable[[bytes], bytes]]) -> Path:
    """A ROS 1 bag of CompressedImage frames on /cam0/image_raw at start_ns + i, frame i's data passed through
    damage[i] where given (rosbags needed)."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    from appdgen.synth.recording import image_message

    store, msgtype = get_typestore(Stores.ROS2_HUMBLE), "sensor_msgs/msg/CompressedImage"
    with Writer(path) as writer:
        connection = writer.add_connection("/cam0/image_raw", msgtype, typestore=store)
        for i, image in enumerate(images):
            message = image_message(store, image, start_ns + i, compressed=compressed)
            if i in damage:
                message.data = np.frombuffer(damage[i](bytes(message.data)), np.uint8).copy()
            writer.write(connection, start_ns + i, store.serialize_ros1(message, msgtype))
    return path


def write_png(path: Path, image: np.ndarray) -> Path:
    """Write a PNG, creating folders."""
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), image)
    return path


@dataclass(frozen=True)
class Setup:
    """A small build's inputs on disk and its standard options (40 samples in 5 shards of 87x32)."""

    calib: Path
    images: Path
    samples: int = 40
    shard_size: int = 8
    size: str = "87x32"
    seed: int = 7

    def args(self, out: Path, *extra: str, jobs: int = 1) -> list[str]:
        """`appdgen build` arguments into `out` (extra options are appended)."""
        return ["build", "--calib", str(self.calib), "--images", str(self.images), "--out", str(out),
                "--samples", str(self.samples), "--shard-size", str(self.shard_size), "--size", self.size,
                "--seed", str(self.seed), "--jobs", str(jobs), "--quiet", *extra]

    def indices(self, shard: int) -> range:
        """Sample indices of a shard."""
        return range(shard * self.shard_size, min((shard + 1) * self.shard_size, self.samples))

    @property
    def shard_count(self) -> int:
        """Number of shards."""
        return -(-self.samples // self.shard_size)


def run_cli(args: list[str]) -> Result:
    """`appdgen ARGS` in this process (stderr kept apart from stdout)."""
    return CliRunner().invoke(main, args, catch_exceptions=True)


def cli_command(args: list[str]) -> list[str]:
    """The command line running `appdgen ARGS` in a fresh interpreter."""
    return [sys.executable, "-m", "appdgen.cli", *args]


def spawn_cli(args: list[str], log: Path) -> subprocess.Popen:
    """Start `appdgen ARGS` in its own process group (so a kill reaches its workers too), stderr to `log`."""
    with open(log, "wb") as stream:
        return subprocess.Popen(cli_command(args), stdout=subprocess.DEVNULL, stderr=stream, start_new_session=True)


def kill_group(process: subprocess.Popen) -> None:
    """SIGKILL a process started by spawn_cli and everything in its group, and reap it."""
    try:
        os.killpg(process.pid, signal.SIGKILL)
    except ProcessLookupError:  # already gone with its group
        pass
    process.wait()


def assert_one_line_error(result: Result, *fragments: str) -> str:
    """Exit status 2, no traceback, nothing on stdout, one `appdgen: error:` line holding every fragment."""
    lines = result.stderr.splitlines()
    assert result.exit_code == 2 and isinstance(result.exception, SystemExit), (result.exit_code, result.output)
    assert len(lines) == 1 and lines[0].startswith("appdgen: error: "), result.stderr
    assert result.stdout == "" and "Traceback" not in result.stderr
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])
    return lines[0]


def tree_digest(path: Path) -> dict[str, str]:
    """Every entry under `path` (or `path` itself when a file) → sha256 of its bytes, or 'dir'; {} when absent."""
    if path.is_file():
        return {".": hashlib.sha256(path.read_bytes()).hexdigest()}
    entries = sorted(path.rglob("*")) if path.is_dir() else []
    return {p.relative_to(path).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
            for p in entries}


def outputs(out: Path) -> dict[str, bytes]:
    """The bytes that must not depend on jobs, backend or interruptions: shards and labels.parquet."""
    return {p.name: p.read_bytes() for p in sorted(out.glob("shard-*.tar")) + [out / "labels.parquet"]}


def assert_same_build(out: Path, reference: Path) -> None:
    """Shards and labels.parquet byte-identical to the reference build's, and no other names (no leftovers)."""
    assert outputs(out) == outputs(reference)
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in reference.iterdir())


def shard_members(path: Path) -> dict[str, bytes]:
    """A shard's members by name, read strictly: plain files with safe relative names, sizes as declared."""
    members: dict[str, bytes] = {}
    with tarfile.open(fileobj=io.BytesIO(path.read_bytes()), mode="r:") as tar:
        for info in tar.getmembers():
            assert info.isreg(), f"{path}: {info.name} is not a plain file"
            assert info.name == Path(info.name).name and info.name not in (".", ".."), info.name  # flat, relative
            data = tar.extractfile(info).read()
            assert len(data) == info.size and info.name not in members
            members[info.name] = data
    return members


def assert_shard_complete(path: Path, setup: Setup, rows: list[dict] | None = None) -> None:
    """A complete shard: one json and one image per sample of its range; when rows are given, they agree."""
    indices = setup.indices(int(path.name.removeprefix("shard-").removesuffix(".tar")))
    members = shard_members(path)
    assert sorted(members) == sorted(f"{i:09d}.{ext}" for i in indices for ext in ("json", "png")), path
    for row in rows or []:
        key = row["key"]
        assert json.loads(members[f"{key}.json"]) == member_record(row)  # the row minus its index-only columns
        assert hashlib.sha256(members[f"{key}.png"]).hexdigest() == row["sha256"]


def fragment_rows(out: Path, shard: str) -> list[dict] | None:
    """The label rows of an unfinished build's shard fragment, or None when the fragment is not written yet."""
    path = out / ".parts" / f"{shard}.parquet"
    return pq.read_table(path).to_pylist() if path.is_file() else None


def assert_killed_build_sound(out: Path, setup: Setup) -> None:
    """What a killed build leaves: every visible shard complete, and matching its fragment when there is one."""
    for path in sorted(out.glob("shard-*.tar")):
        assert_shard_complete(path, setup, fragment_rows(out, path.name))


class FullDisk:
    """Stands in for `os` inside appdgen.util.atomic: the Nth fsync fails with ENOSPC, as on a full disk."""

    def __init__(self, fail_at: int) -> None:
        self.fail_at, self.calls = fail_at, 0

    def __getattr__(self, name: str) -> object:
        """Everything but fsync is the real os module's."""
        return getattr(os, name)

    def fsync(self, fd: int) -> None:
        """os.fsync, except on the fail_at-th call."""
        self.calls += 1
        if self.calls == self.fail_at:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        os.fsync(fd)


def run_with_full_disk(args: list[str], fail_at: int) -> Result:
    """`appdgen ARGS` in this process (use --jobs 1) with the fail_at-th atomic write failing for lack of space."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(appdgen.util.atomic, "os", FullDisk(fail_at))
        return run_cli(args)


def sampler_draws(job: tuple[Calibration, tuple[int, int], int, range, float | None]) -> list[tuple[float, bool]]:
    """(estimate %, is reference) of draws `indices` of `seed` (max_fov in degrees), each checked by the full crop."""
    reference, size, seed, indices, max_fov = job
    sampler = Sampler(reference, size=size, max_fov=max_fov)
    draws = [sampler.draw(seed, i) for i in indices]
    for draw in draws:
        valid_region(draw.calib, max_fov=max_fov)  # raises AppdgenError for an invalid calibration
    return [(d.estimate_pct, d.is_reference) for d in draws]
