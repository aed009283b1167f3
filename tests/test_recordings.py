"""Recordings as sources (issue 20): ROS 1/ROS 2 bags and videos written by rosbags' and PyAV's own writers."""
from __future__ import annotations

import builtins
import json
import shutil
import time
from pathlib import Path

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest

# The recordings' extras (appdgen[ros], appdgen[video]): make test installs them; without them these tests skip.
pytest.importorskip("rosbags")
pytest.importorskip("av")

from appdgen.synth.recording import FRAME_PERIOD_NS, START_NS, write_bag, write_video
from helpers import (
    assert_one_line_error,
    assert_same_build,
    compressed_bag,
    kill_group,
    kitti_text,
    raw_image,
    run_cli,
    run_with_full_disk,
    shard_members,
    spawn_cli,
    write_png,
)

FRAMES = 6


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory, small_camera) -> Path:
    """The small camera's calibration, its frames as PNGs, and the same frames as a ROS 1 bag, ROS 2 bags (mcap
    Image, mcap CompressedImage, sqlite3 rgb8), a mono bag and a video."""
    root = tmp_path_factory.mktemp("recordings")
    (root / "calib.txt").write_text(kitti_text({"02": small_camera}))
    frames = [raw_image(small_camera.size, i) for i in range(FRAMES)]
    grey = [cv2.cvtColor(f, cv2.COLOR_BGR2GRAY) for f in frames]
    for i, frame in enumerate(frames):
        write_png(root / "png" / f"{i:03d}.png", frame)
        write_png(root / "grey" / f"{i:03d}.png", grey[i])
    write_bag(root / "run.bag", frames)
    write_bag(root / "mcap", frames, kind="mcap")
    write_bag(root / "jpeg", frames, kind="mcap", compressed="jpeg")
    write_bag(root / "db3", frames, kind="db3", encoding="rgb8")
    write_bag(root / "mono.bag", grey)
    write_video(root / "run.mp4", frames)
    return root


def build_args(root: Path, images: str | Path, out: Path, *extra: str, jobs: int = 1) -> list[str]:
    """A small build of 24 samples in 3 shards at 87x32 from `images`."""
    return ["build", "--calib", str(root / "calib.txt"), "--images", str(images), "--out", str(out),
            "--samples", "24", "--shard-size", "8", "--size", "87x32", "--seed", "5", "--jobs", str(jobs),
            "--quiet", *extra]


def images_of(out: Path) -> dict[str, np.ndarray]:
    """Every sample image of a build, decoded as stored (grey stays 2-D)."""
    found = {}
    for shard in sorted(out.glob("shard-*.tar")):
        for name, data in shard_members(shard).items():
            if name.endswith(".png"):
                found[name] = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    return found


def build(root: Path, images: str | Path, out: Path, *extra: str, jobs: int = 1) -> Path:
    """Run a build that must succeed."""
    result = run_cli(build_args(root, images, out, *extra, jobs=jobs))
    assert result.exit_code == 0, result.output
    return out


def same_images(a: dict, b: dict) -> bool:
    """Whether two builds hold the same sample images."""
    return a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


@pytest.fixture(scope="module")
def png_build(inputs: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The build from the PNG folder: what a lossless recording of the same frames must give."""
    return build(inputs, inputs / "png", tmp_path_factory.mktemp("png") / "out")


@pytest.mark.parametrize("name", ["run.bag", "mcap", "db3", "mcap/mcap.mcap", "db3/db3.db3"])
def test_lossless_bags_give_the_samples_of_the_same_pngs(name: str, inputs: Path, png_build: Path,
                                                         tmp_path: Path) -> None:
    out = build(inputs, inputs / name, tmp_path / "out")
    assert same_images(images_of(out), images_of(png_build))
    info = json.loads((out / "build.json").read_text())
    assert info["channels"] == 3 and len(info["recordings_sha256"]) == 1


def test_labels_say_where_each_frame_came_from(inputs: Path, png_build: Path, tmp_path: Path) -> None:
    out = build(inputs, inputs / "run.bag", tmp_path / "out")
    bag = pq.read_table(out / "labels.parquet").to_pylist()
    png = pq.read_table(png_build / "labels.parquet").to_pylist()
    for row, twin in zip(bag, png, strict=True):
        number = int(Path(twin["raw_path"]).stem)  # the PNG folder names frame i i.png
        assert (row["source"], row["topic"], row["frame"]) == (str(inputs / "run.bag"), "/cam0/image_raw", number)
        assert row["timestamp_ns"] == START_NS + number * FRAME_PERIOD_NS
        assert row["raw_path"] == f"{inputs / 'run.bag'}/cam0/image_raw/{row['timestamp_ns']}"
        assert row["appd_pct"] == twin["appd_pct"]
        members = shard_members(out / row["shard"])
        assert json.loads(members[f"{row['key']}.json"])["timestamp_ns"] == row["timestamp_ns"]
    assert run_cli(["verify", str(out)]).exit_code == 0


def test_compressed_and_video_frames_decode_as_their_libraries_do(inputs: Path, tmp_path: Path) -> None:
    import av

    jpegs = [cv2.imdecode(cv2.imencode(".jpg", raw_image((174, 64), i))[1], cv2.IMREAD_COLOR) for i in range(FRAMES)]
    with av.open(str(inputs / "run.mp4")) as container:
        videos = [f.to_ndarray(format="bgr24") for f in container.decode(video=0)]
    assert len(videos) == FRAMES
    for name, frames in (("jpeg", jpegs), ("run.mp4", videos)):
        for i, frame in enumerate(frames):
            write_png(tmp_path / name / f"{i:03d}.png", frame)
        ours = images_of(build(inputs, inputs / name, tmp_path / f"out-{name}"))
        assert same_images(ours, images_of(build(inputs, tmp_path / name, tmp_path / f"png-{name}")))


def test_every_min_interval_and_window_choose_frames(inputs: Path, tmp_path: Path) -> None:
    def frames(*options: str) -> list[int]:
        out = build(inputs, inputs / "run.bag", tmp_path / "-".join(options or ("all",)), *options)
        return sorted(set(pq.read_table(out / "labels.parquet")["frame"].to_pylist()))

    assert frames() == [0, 1, 2, 3, 4, 5]
    assert frames("--every", "2") == [0, 2, 4]
    assert frames("--min-interval", "0.25") == [0, 3]  # 10 Hz: 0.3 s is the first gap of at least 0.25 s
    assert frames("--start", "0.1", "--end", "0.35") == [1, 2, 3]
    assert frames("--every", "2", "--start", "0.1") == [1, 3, 5]


def test_mono_bag_and_grey_pngs_give_one_channel_samples(inputs: Path, tmp_path: Path) -> None:
    mono = build(inputs, inputs / "mono.bag", tmp_path / "mono")
    grey = build(inputs, inputs / "grey", tmp_path / "grey")
    assert json.loads((mono / "build.json").read_text())["channels"] == 1
    assert all(image.ndim == 2 for image in images_of(mono).values())
    assert same_images(images_of(mono), images_of(grey))
    colour = images_of(build(inputs, inputs / "mono.bag", tmp_path / "three", "--channels", "3"))
    assert all(np.array_equal(c, cv2.cvtColor(images_of(mono)[k], cv2.COLOR_GRAY2BGR)) for k, c in colour.items())
    flat = images_of(build(inputs, inputs / "run.bag", tmp_path / "flat", "--channels", "1"))
    assert all(image.ndim == 2 for image in flat.values())


def test_jobs_and_an_interrupted_build_give_the_same_bytes(inputs: Path, tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    one = build(inputs, inputs / "jpeg", tmp_path / "one")
    build(inputs, inputs / "jpeg", tmp_path / "two", jobs=2)
    assert_same_build(tmp_path / "two", one)
    args = build_args(inputs, inputs / "jpeg", tmp_path / "cut")
    assert run_with_full_disk(args, 4).exit_code == 2  # the disk fills during shard 1
    monkeypatch.chdir(inputs)  # resumed from another folder, the recording named by another path
    assert run_cli([*build_args(inputs, "jpeg", tmp_path / "cut"), "--resume"]).exit_code == 0
    assert_same_build(tmp_path / "cut", one)
    copy, changed = tmp_path / "copy", tmp_path / "changed"
    shutil.copytree(inputs / "jpeg", copy)
    assert run_with_full_disk(build_args(inputs, copy, changed), 4).exit_code == 2
    shutil.rmtree(copy)  # the same frames' timestamps, other pixels: only the recording's hash tells
    write_bag(copy, [raw_image((174, 64), 9)] * FRAMES, kind="mcap", compressed="jpeg")
    assert_one_line_error(run_cli([*build_args(inputs, copy, changed), "--resume"]), "used other inputs")


def test_kill_9_then_resume_gives_identical_shards(inputs: Path, tmp_path: Path) -> None:
    def args(out: Path, *extra: str) -> list[str]:  # 12 shards (a later option wins): the kill lands mid-build
        return build_args(inputs, inputs / "jpeg", out, "--samples", "48", "--shard-size", "4", *extra, jobs=2)

    reference = build(inputs, inputs / "jpeg", tmp_path / "reference", "--samples", "48", "--shard-size", "4")
    out = tmp_path / "out"
    process = spawn_cli(args(out), tmp_path / "log")
    try:
        while not (out / ".parts" / "shard-000000.tar.parquet").exists() and process.poll() is None:
            time.sleep(0.005)
    finally:
        kill_group(process)
    assert (out / ".parts" / "plan.json").is_file(), (tmp_path / "log").read_text()  # killed mid-build
    assert run_cli(args(out, "--resume")).exit_code == 0
    assert_same_build(out, reference)


def test_split_by_recording_and_the_trainers_holdout(inputs: Path, tmp_path: Path) -> None:
    folder = tmp_path / "runs"
    folder.mkdir()
    for name in ("a.bag", "b.bag", "c.mp4"):
        (folder / name).symlink_to(inputs / ("run.mp4" if name.endswith("mp4") else "run.bag"))
    out = build(inputs, folder, tmp_path / "out", "--split-by", "recording")
    table = pq.read_table(out / "labels.parquet").to_pydict()
    assert sorted(set(table["split"])) == ["a.bag", "b.bag", "c.mp4"]
    assert sorted(set(table["source"])) == ["a.bag", "b.bag", "c.mp4"]
    pytest.importorskip("torch")  # the trainer's holdout keeps each recording whole
    from train.holdout import holdout_group

    groups = {holdout_group(r, s) for r, s in zip(table["raw_path"], table["source"], strict=True)}
    assert groups == {"a.bag", "b.bag", "c.mp4"}


def _kalibr(path: Path, small_camera, topics: dict[str, str]) -> Path:
    """A Kalibr camchain of the small camera once per (camera, rostopic)."""
    c = small_camera
    blocks = [f"{name}:\n  camera_model: pinhole\n  distortion_model: radtan\n"
              f"  distortion_coeffs: [{c.k1!r}, {c.k2!r}, {c.p1!r}, {c.p2!r}]\n"
              f"  intrinsics: [{c.fx!r}, {c.fy!r}, {c.cx!r}, {c.cy!r}]\n  resolution: [{c.width}, {c.height}]\n"
              f"  rostopic: {topic}\n" for name, topic in topics.items()]
    path.write_text("".join(blocks))
    return path


def _two_topic_bag(path: Path, size: tuple[int, int]) -> Path:
    """A ROS 1 bag with frames on /cam0/image_raw and /cam1/image_raw (cam1's frames are its cam0's inverted)."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    from appdgen.synth.recording import image_message

    store = get_typestore(Stores.ROS2_HUMBLE)
    with Writer(path) as writer:
        connections = [writer.add_connection(f"/cam{i}/image_raw", "sensor_msgs/msg/Image", typestore=store)
                       for i in range(2)]
        for n in range(3):
            for i, connection in enumerate(connections):
                image = raw_image(size, n) if i == 0 else 255 - raw_image(size, n)
                writer.write(connection, START_NS + n, store.serialize_ros1(image_message(store, image, n),
                                                                            "sensor_msgs/msg/Image"))
    return path


def test_topic_comes_from_the_calibrations_rostopic(inputs: Path, small_camera, tmp_path: Path) -> None:
    bag = _two_topic_bag(tmp_path / "two.bag", small_camera.size)
    chain = _kalibr(tmp_path / "camchain.yaml", small_camera, {"cam0": "/cam0/image_raw", "cam1": "/cam1/image_raw"})
    args = ["build", "--calib", str(chain), "--images", str(bag), "--samples", "6", "--size", "87x32", "--quiet",
            "--jobs", "1"]
    result = run_cli([*args, "--camera", "cam1", "--out", str(tmp_path / "cam1")])
    assert result.exit_code == 0, result.output
    assert set(pq.read_table(tmp_path / "cam1" / "labels.parquet")["topic"].to_pylist()) == {"/cam1/image_raw"}
    assert_one_line_error(run_cli([*args, "--out", str(tmp_path / "x")]), str(chain), "cam0, cam1", "--camera")
    plain = tmp_path / "plain.txt"
    plain.write_text(kitti_text({"02": small_camera}))
    assert_one_line_error(run_cli(["build", "--calib", str(plain), "--images", str(bag), "--out",
                                   str(tmp_path / "y")]), str(bag), "/cam0/image_raw, /cam1/image_raw", "--topic")
    assert_one_line_error(run_cli([*args, "--camera", "cam0", "--topic", "/nope", "--out", str(tmp_path / "z")]),
                          str(bag), "no image topic /nope")
    elsewhere = _kalibr(tmp_path / "other.yaml", small_camera, {"cam0": "/left/image"})
    assert_one_line_error(run_cli([*args[:2], str(elsewhere), *args[3:], "--out", str(tmp_path / "w")]),
                          str(bag), "rostopic /left/image", "--topic")
    assert not any((tmp_path / name).exists() for name in ("x", "y", "z", "w"))


@pytest.mark.parametrize("kind", ["bag", "db3", "video"])
def test_synth_writes_its_frames_as_a_recording(kind: str, tmp_path: Path) -> None:
    png, rec = tmp_path / "png", tmp_path / kind
    for out, extra in ((png, []), (rec, ["--as", kind, "--mono"])):
        result = run_cli(["synth", "--frames", "3", "--scale", "0.125", "--jobs", "1", "--quiet", "--out", str(out),
                          *extra])
        assert result.exit_code == 0, result.output
    from appdgen.synth.recording import RECORDING_NAMES

    target = rec / RECORDING_NAMES[kind]
    assert sorted(p.name for p in rec.iterdir()) == sorted(["calibration.yaml", target.name])
    from appdgen.sources.recordings import FrameChoice, stream, topics

    got = [decode() for _, decode in stream(target, topics(target)[0], FrameChoice())]
    expected = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted(png.glob("*.png"))]
    assert len(got) == 3
    if kind == "video":  # lossy, and colour: grey frames through yuv420p MPEG-4 at its finest quantiser
        assert all(g.ndim == 3 for g in got)
        grey = [cv2.cvtColor(g, cv2.COLOR_BGR2GRAY).astype(int) for g in got]
        errors = np.array([[np.abs(g - e).mean() for e in expected] for g in grey])
        assert (errors.argmin(1) == np.arange(3)).all() and errors.diagonal().max() < 8  # each is its own frame
    else:
        assert all(np.array_equal(g, e) for g, e in zip(got, expected, strict=True))
    assert_one_line_error(run_cli(["synth", "--frames", "1", "--scale", "0.125", "--out", str(rec), "--as", kind]),
                          "exists already")


def test_a_folder_of_images_keeps_a_stray_video_out(inputs: Path, png_build: Path, tmp_path: Path) -> None:
    folder = tmp_path / "png"
    folder.mkdir()
    for path in sorted((inputs / "png").glob("*.png")):
        (folder / path.name).symlink_to(path)
    (folder / "stray.mp4").symlink_to(inputs / "run.mp4")
    assert same_images(images_of(build(inputs, folder, tmp_path / "out")), images_of(png_build))


# --- image encodings ---------------------------------------------------------------------------------------------


def _one_message(encoding: str, pixels: np.ndarray):
    """An Image message holding `pixels` under `encoding`, through rosbags' CDR round trip."""
    from rosbags.typesys import Stores, get_typestore

    from appdgen.synth.recording import image_message

    store = get_typestore(Stores.ROS2_HUMBLE)
    raw = store.serialize_cdr(image_message(store, pixels, 0, encoding), "sensor_msgs/msg/Image")
    return store.deserialize_cdr(raw, "sensor_msgs/msg/Image")


def test_encodings_decode_to_grey_or_bgr() -> None:
    from appdgen.sources.bags import IMAGE, decode_message

    bgr = raw_image((10, 6), 1)
    grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    deep = np.arange(60, dtype=np.uint16).reshape(6, 10) * 1000
    bayer = grey  # any 1-channel mosaic: compared with OpenCV's own demosaicing of it
    cases = {"bgr8": (bgr, bgr), "rgb8": (bgr, bgr), "mono8": (grey, grey),
             "mono16": (deep, (deep // 256).astype(np.uint8)),
             "bgra8": (cv2.cvtColor(bgr, cv2.COLOR_BGR2BGRA), bgr),
             "bayer_rggb8": (bayer, cv2.cvtColor(bayer, cv2.COLOR_BayerBG2BGR)),
             "bayer_grbg8": (bayer, cv2.cvtColor(bayer, cv2.COLOR_BayerGB2BGR))}
    for encoding, (pixels, expected) in cases.items():
        decoded = decode_message(_one_message(encoding, pixels), IMAGE, "test")
        assert decoded.dtype == np.uint8 and np.array_equal(decoded, expected), encoding


# --- bad input ---------------------------------------------------------------------------------------------------


def test_truncated_recordings_fail_in_one_line_writing_nothing(inputs: Path, tmp_path: Path) -> None:
    for name in ("run.bag", "run.mp4", "mcap/mcap.mcap"):
        cut = tmp_path / Path(name).name
        data = (inputs / name).read_bytes()
        cut.write_bytes(data[:len(data) // 2])
        out = tmp_path / f"out-{cut.name}"
        assert_one_line_error(run_cli(build_args(inputs, cut, out)), str(cut))
        assert not out.exists()


def test_bad_frames_are_refused_or_skipped_and_counted(inputs: Path, small_camera, tmp_path: Path) -> None:
    frames = [raw_image(small_camera.size, i) for i in range(4)]
    frames[2] = raw_image((80, 40), 2)
    bag = tmp_path / "sizes.bag"
    write_bag(bag, frames)
    out = tmp_path / "out"
    assert_one_line_error(run_cli(build_args(inputs, bag, out)), str(bag), "/cam0/image_raw",
                          str(START_NS + 2 * FRAME_PERIOD_NS), "80x40", "--skip-bad")
    assert not out.exists()
    result = run_cli(build_args(inputs, bag, out, "--skip-bad"))
    assert result.exit_code == 0 and "1 images skipped" in result.output
    assert sorted(set(pq.read_table(out / "labels.parquet")["frame"].to_pylist())) == [0, 1, 3]
    assert json.loads((out / "build.json").read_text())["counts"]["skipped_images"][0]["problem"].startswith("is 80x40")
    odd = tmp_path / "odd.bag"
    write_bag(odd, frames[:2], encoding="yuv422")
    assert_one_line_error(run_cli(build_args(inputs, odd, tmp_path / "o")), str(odd), "unknown encoding 'yuv422'")
    video = tmp_path / "small.mp4"
    write_video(video, [raw_image((80, 40), i) for i in range(3)])
    assert_one_line_error(run_cli(build_args(inputs, video, tmp_path / "v")), str(video), "is 80x40")
    assert not any((tmp_path / name).exists() for name in ("o", "v"))


def test_a_bag_without_image_topics_is_refused(inputs: Path, tmp_path: Path) -> None:
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    bag = tmp_path / "imu.bag"
    with Writer(bag) as writer:
        connection = writer.add_connection("/imu", "std_msgs/msg/String", typestore=store)
        writer.write(connection, START_NS, store.serialize_ros1(store.types["std_msgs/msg/String"](data="x"),
                                                                 "std_msgs/msg/String"))
    assert_one_line_error(run_cli(build_args(inputs, bag, tmp_path / "out")), str(bag), "no sensor_msgs/Image")
    assert_one_line_error(run_cli(build_args(inputs, bag, tmp_path / "out", "--topic", "/imu")), str(bag),
                          "no image topic /imu")


@pytest.mark.parametrize(("name", "module", "extra"), [("run.bag", "rosbags", "appdgen[ros]"),
                                                       ("run.mp4", "av", "appdgen[video]")])
def test_a_missing_extra_is_named(name: str, module: str, extra: str, inputs: Path, tmp_path: Path,
                                  monkeypatch: pytest.MonkeyPatch) -> None:
    real = builtins.__import__

    def without(what, *args, **kwargs):
        if what == module or what.startswith(module + "."):
            raise ImportError(f"No module named {what!r}")
        return real(what, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", without)
    assert_one_line_error(run_cli(build_args(inputs, inputs / name, tmp_path / "out")), f"pip install '{extra}'")


def test_the_calibrations_topic_finds_its_compressed_twin(small_camera, tmp_path: Path) -> None:
    from appdgen.sources.recordings import choose_topic

    bag = tmp_path / "compressed.bag"
    write_bag(bag, [raw_image(small_camera.size, 0)], topic="/cam0/image_raw/compressed", compressed="jpeg")
    assert choose_topic(bag, None, "/cam0/image_raw") == "/cam0/image_raw/compressed"
    assert choose_topic(bag, None, None) == "/cam0/image_raw/compressed"


def test_skip_bad_decodes_compressed_frames_and_drops_the_undecodable(inputs: Path, small_camera,
                                                                     tmp_path: Path) -> None:
    def flip(data: bytes) -> bytes:
        """Header and IEND intact, a byte of the compressed pixels flipped: libpng refuses it."""
        return data[:len(data) // 2] + bytes([data[len(data) // 2] ^ 0xFF]) + data[len(data) // 2 + 1:]

    bag = compressed_bag(tmp_path / "garbled.bag", [raw_image(small_camera.size, i) for i in range(3)], START_NS,
                         "png", {1: flip})
    out = tmp_path / "out"
    result = run_cli(build_args(inputs, bag, out, "--skip-bad"))
    assert result.exit_code == 0 and "1 images skipped" in result.output, result.output
    assert sorted(set(pq.read_table(out / "labels.parquet")["frame"].to_pylist())) == [0, 2]
    # Without --skip-bad only headers are read up front: the worker that meets the frame stops the build, naming it.
    assert_one_line_error(run_cli(build_args(inputs, bag, tmp_path / "stopped")), str(bag), "/cam0/image_raw",
                          f"{START_NS + 1} ns", "undecodable png", "--resume")
