"""`appdgen detect` (issue 32, item 4): its JSON and table against the library's own readings, sequences, abstention,
the baseline round trip, --images as a glob and a list file, and one line (exit 2) for every bad input."""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from appdgen.calib.formats import list_cameras, load
from appdgen.synth import scale_calibration
from helpers import assert_one_line_error, run_cli, write_png

SEQUENCE = 3  # frames pooled per sequence in these tests: 7 listed frames make groups of 3, 3 and 1


@dataclass(frozen=True)
class Street:
    """Synthetic street frames of KITTI camera 02 at quarter size, a blank frame, and a list file of them all."""

    root: Path
    calib: Path
    frames: list[Path]  # the listed frames, in the list's order (not sorted: the blank one second)
    listing: Path


@pytest.fixture(scope="module", autouse=True)
def model_cache(tmp_path_factory: pytest.TempPathFactory):
    """Every belief's model cached in one folder for this module (built once, read by every later test)."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("APPDGEN_CACHE", str(tmp_path_factory.mktemp("cache")))
        yield


@pytest.fixture(scope="module")
def street(tmp_path_factory: pytest.TempPathFactory) -> Street:
    """Six synthetic street frames and a blank one, listed out of name order."""
    root = tmp_path_factory.mktemp("street")
    result = run_cli(["synth", "--frames", "6", "--scale", "0.25", "--out", str(root / "raw"), "--quiet"])
    assert result.exit_code == 0, result.output
    calib = root / "raw" / "calibration.yaml"
    width, height = load(calib).size
    blank = write_png(root / "blank" / "wall.png", np.full((height, width), 128, np.uint8))
    raw = sorted((root / "raw").glob("*.png"))
    frames = [raw[0], blank, raw[3], raw[1], raw[2], raw[4], raw[5]]
    listing = root / "frames.txt"
    listing.write_text("".join(f"{p.relative_to(root).as_posix()}\n" for p in frames))
    return Street(root, calib, frames, listing)


@pytest.fixture(scope="module")
def baseline(street: Street, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The street camera's baseline, saved by the command from its six frames under its own calibration."""
    path = tmp_path_factory.mktemp("baseline") / "made" / "baseline.json"
    result = detect(street, "--save-baseline", str(path), images=str(street.root / "raw"))
    assert result.exit_code == 0 and path.is_file(), result.output
    assert result.stdout.splitlines()[-1] == f"baseline of 6 frames under {street.calib} -> {path}"
    return path


def detect(street: Street, *args: str, calib: Path | None = None, images: str | None = None):
    """`appdgen detect` on the street's list (or `images`) with its calibration (or `calib`), sequences of 3."""
    return run_cli(["detect", "--calib", str(calib or street.calib), "--images", images or str(street.listing),
                    "--sequence", str(SEQUENCE), "--quiet", *args])


def read_json(street: Street, tmp_path: Path, *args: str, **where) -> dict:
    """The --json document of a successful run."""
    out = tmp_path / "detect.json"
    result = detect(street, "--json", str(out), *args, **where)
    assert result.exit_code == 0, result.output
    return json.loads(out.read_text())


def test_the_json_holds_every_frame_in_input_order_and_the_library_s_readings(street: Street, tmp_path: Path):
    from appdgen.detect import Detector
    from appdgen.sources.decode import read_image

    document = read_json(street, tmp_path)
    frames, sequences, summary = document["frames"], document["sequences"], document["summary"]
    assert [f["image"] for f in frames] == [p.relative_to(street.root).as_posix() for p in street.frames]
    assert set(frames[0]) == {"image", "appd_pct", "appd_sd_pct", "bend_pct", "bend_sd_pct", "p_above", "verdict",
                              "segments", "reason", "raw_appd_pct", "raw_appd_sd_pct"}
    detector = Detector(load(street.calib))
    evidence = [detector.evidence(read_image(p, 1), p.name) for p in street.frames]
    for entry, one in zip(frames, evidence, strict=True):
        alone = detector.read([one]).to_dict()
        assert {k: entry[k] for k in ("appd_pct", "bend_pct", "segments", "verdict")} == \
               {k: alone[k] for k in ("appd_pct", "bend_pct", "segments", "verdict")}
    pooled = detector.read(evidence[3:6]).to_dict()  # the second sequence, pooled in one solve
    assert sequences[1]["appd_pct"] == pooled["appd_pct"] and sequences[1]["offsets"] == pooled["offsets"]
    assert summary["frames"] == 7 and summary["camera"] == list_cameras(street.calib)[0]
    assert summary["calibration"] == str(street.calib) and summary["size"] == list(load(street.calib).size)
    assert summary["abstained"] == sum(f["appd_pct"] is None for f in frames) >= 1
    assert summary["threshold_pct"] == 0.5 and summary["baseline"] is None and summary["model_seconds"] > 0
    assert summary["frames_per_second"] > 0


def test_sequences_are_consecutive_groups_the_last_holding_what_is_left(street: Street, tmp_path: Path):
    from appdgen.detect import Detector
    from appdgen.sources.decode import read_image

    sequences = read_json(street, tmp_path)["sequences"]
    assert [(s["first"], s["count"]) for s in sequences] == [(0, 3), (3, 3), (6, 1)]
    assert [s["first_image"] for s in sequences] == [p.relative_to(street.root).as_posix()
                                                     for p in (street.frames[0], street.frames[3], street.frames[6])]
    detector = Detector(load(street.calib))
    evidence = [detector.evidence(read_image(p, 1), p.name) for p in street.frames]
    for entry in sequences:
        pooled = detector.read(evidence[entry["first"]:entry["first"] + entry["count"]]).to_dict()
        assert entry["verdict"] == pooled["verdict"] and entry["p_above"] == pooled["p_above"]
        assert entry["appd_pct"] is None or entry["appd_sd_pct"] > 0 and set(entry["offsets"]) <= {
            "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"}


def test_a_blank_frame_abstains_with_its_reason(street: Street, tmp_path: Path):
    blank = read_json(street, tmp_path)["frames"][1]
    assert blank["appd_pct"] is None and blank["bend_pct"] is None and blank["p_above"] is None
    assert blank["verdict"] == "abstain" and isinstance(blank["reason"], str) and blank["reason"]


def test_the_table_has_a_line_per_sequence_and_per_frame_unless_quiet(street: Street):
    quiet = detect(street)
    assert quiet.exit_code == 0, quiet.output
    loud = run_cli(["detect", "--calib", str(street.calib), "--images", str(street.listing), "--sequence", "3"])
    assert loud.exit_code == 0, loud.output
    lines = quiet.stdout.splitlines()
    assert lines[0].startswith("belief raw/calibration.yaml camera") and "against straight lines" in lines[0]
    assert lines[1].startswith("frames") and [line.split()[0] for line in lines[2:5]] == ["0-2", "3-5", "6"]
    assert "7 frames (" in lines[-1] and "3 sequences of 3" in lines[-1]
    assert "blank/wall.png" in loud.stdout and "abstain:" in loud.stdout and "blank/wall.png" not in quiet.stdout
    assert "frames" in loud.stderr  # the progress line


def test_a_glob_and_a_folder_read_the_same_frames_as_the_list(street: Street, tmp_path: Path):
    by_glob = read_json(street, tmp_path, images=str(street.root / "raw" / "frame_*.png"))["frames"]
    by_folder = read_json(street, tmp_path, images=str(street.root / "raw"))["frames"]
    listed = {Path(f["image"]).name: f for f in read_json(street, tmp_path)["frames"]}
    assert [Path(f["image"]).name for f in by_glob] == [f"frame_{i:06d}.png" for i in range(6)]
    assert [f["image"] for f in by_folder] == [f"frame_{i:06d}.png" for i in range(6)]
    for entry in by_glob:
        assert entry["appd_pct"] == listed[Path(entry["image"]).name]["appd_pct"]


def test_a_bag_of_the_same_frames_reads_as_the_png_files(street: Street, tmp_path: Path):
    pytest.importorskip("rosbags")
    result = run_cli(["synth", "--frames", "3", "--scale", "0.25", "--out", str(tmp_path), "--as", "bag", "--mono",
                      "--quiet"])  # the street's first three frames (same seed), grey, on /cam0/image_raw
    assert result.exit_code == 0, result.output
    from_bag = read_json(street, tmp_path, images=str(tmp_path / "recording.bag"))
    from_files = read_json(street, tmp_path, images=str(street.root / "raw"))
    names = [f["image"] for f in from_bag["frames"]]
    assert len(names) == 3 and all(n.startswith(f"{tmp_path / 'recording.bag'}/cam0/image_raw/") for n in names)
    assert sorted(names) == names
    for key in ("appd_pct", "bend_pct", "segments"):
        assert [f[key] for f in from_bag["frames"]] == [f[key] for f in from_files["frames"][:3]]


def test_the_baseline_round_trip_reads_as_the_library_does_with_that_file(street: Street, baseline: Path,
                                                                          tmp_path: Path):
    from appdgen.detect import Baseline, Detector
    from appdgen.sources.decode import read_image

    against = read_json(street, tmp_path, "--baseline", str(baseline), "--sequence", "7")
    plain = read_json(street, tmp_path, "--sequence", "7")
    assert against["summary"]["baseline"] == str(baseline) and plain["summary"]["baseline"] is None
    detector = Detector(load(street.calib))
    evidence = [detector.evidence(read_image(p, 1), p.name) for p in street.frames]
    expected = detector.read(evidence, Baseline.from_json(baseline)).to_dict()
    assert against["sequences"][0]["appd_pct"] == expected["appd_pct"] is not None
    assert against["sequences"][0]["offsets"] == expected["offsets"]
    assert against["sequences"][0]["appd_pct"] != plain["sequences"][0]["appd_pct"]  # the file took effect
    # The file holds the camera's map, learnt at --save-baseline; the reading is the map's, the raw one kept.
    assert Baseline.from_json(baseline).camera_map is not None
    assert against["sequences"][0]["raw_appd_pct"] == expected["raw_appd_pct"] is not None


def damaged(street: Street, baseline: Path, tmp_path: Path, case: str) -> list[str]:
    """The arguments of one bad input (after `detect`)."""
    calib, images = str(street.calib), str(street.root / "raw")
    if case == "missing calibration":
        return ["--calib", str(tmp_path / "none.yaml"), "--images", images]
    if case == "unreadable calibration":
        (tmp_path / "junk.yaml").write_text("%YAML:1.0\n: : [\n")
        return ["--calib", str(tmp_path / "junk.yaml"), "--images", images]
    if case == "wrong camera":
        return ["--calib", calib, "--camera", "07", "--images", images]
    if case == "no frames":
        (tmp_path / "empty").mkdir()
        return ["--calib", calib, "--images", str(tmp_path / "empty")]
    if case == "frame of another size":
        write_png(tmp_path / "odd" / "x.png", np.zeros((9, 9), np.uint8))
        return ["--calib", calib, "--images", str(tmp_path / "odd")]
    if case == "bad baseline":
        (tmp_path / "b.json").write_text("{not json")
        return ["--calib", calib, "--images", images, "--baseline", str(tmp_path / "b.json")]
    if case == "foreign baseline":  # the street camera's baseline, recorded for a camera of half its size
        document = json.loads(baseline.read_text())
        document["reference"] = scale_calibration(load(street.calib), 0.5).to_dict()
        (tmp_path / "small.json").write_text(json.dumps(document))
        return ["--calib", calib, "--images", images, "--baseline", str(tmp_path / "small.json")]
    if case == "old baseline":  # the street camera's baseline as version 1 wrote it: no camera map
        document = json.loads(baseline.read_text())
        document["version"] = 1
        del document["camera_map"]
        (tmp_path / "old.json").write_text(json.dumps(document))
        return ["--calib", calib, "--images", images, "--baseline", str(tmp_path / "old.json")]
    if case == "baseline and save-baseline":
        return ["--calib", calib, "--images", images, "--baseline", "a.json", "--save-baseline", "b.json"]
    if case == "baseline of a perturbed belief":
        return ["--calib", calib, "--images", images, "--perturb", "fx=0.02", "--save-baseline", "b.json"]
    if case == "unknown parameter":
        return ["--calib", calib, "--images", images, "--perturb", "f=0.02"]
    if case == "sequence 0":
        return ["--calib", calib, "--images", images, "--sequence", "0"]
    if case == "threshold 0":
        return ["--calib", calib, "--images", images, "--threshold", "0"]
    if case == "threshold negative":
        return ["--calib", calib, "--images", images, "--threshold", "-0.5"]
    assert case == "unwritable json"
    (tmp_path / "file").write_text("")
    return ["--calib", calib, "--images", images, "--json", str(tmp_path / "file" / "out.json")]


BAD = {"missing calibration": "none.yaml", "unreadable calibration": "junk.yaml", "wrong camera": "07",
       "no frames": "empty", "frame of another size": "x.png", "bad baseline": "b.json",
       "foreign baseline": "174x64", "old baseline": "old.json: baseline version 1, but this appdgen reads version 5",
       "baseline and save-baseline": "--save-baseline",
       "baseline of a perturbed belief": "--set/--perturb", "unknown parameter": "'f=0.02'", "sequence 0": "--sequence",
       "threshold 0": "--threshold", "threshold negative": "--threshold", "unwritable json": "out.json"}


@pytest.mark.parametrize("case", BAD)
def test_every_bad_input_is_one_line_and_exit_2_writing_nothing(street: Street, baseline: Path, tmp_path: Path,
                                                               case: str):
    args = damaged(street, baseline, tmp_path, case)
    out = tmp_path / "detect.json"
    extra = [] if "--json" in args else ["--json", str(out)]
    result = run_cli(["detect", *args, *extra, "--quiet"])
    assert_one_line_error(result, BAD[case])
    assert not out.exists() and not any(tmp_path.rglob(".*.tmp"))


@pytest.mark.slow
def test_real_euroc_frames_under_their_own_calibration_read_in_order(shared: Path, tmp_path: Path):
    euroc = shared / "real" / "euroc_micro_cam1"
    frames = sorted((euroc / "data").glob("*.png"))[:4]
    listing = tmp_path / "frames.txt"
    listing.write_text("".join(f"{p}\n" for p in frames))
    out = tmp_path / "euroc.json"
    result = run_cli(["detect", "--calib", str(euroc / "sensor.yaml"), "--images", str(listing), "--sequence", "4",
                      "--json", str(out), "--quiet"])
    assert result.exit_code == 0, result.output
    document = json.loads(out.read_text())
    assert [Path(f["image"]).name for f in document["frames"]] == [p.name for p in frames]
    assert document["summary"]["size"] == [752, 480] and document["summary"]["model"] == "radtan"
    for entry in [*document["frames"], *document["sequences"]]:
        assert entry["appd_pct"] is not None or entry["reason"]  # an abstention says why
        assert entry["verdict"] != "miscalibrated", entry
        assert entry["appd_pct"] is None or 0 <= entry["bend_pct"] <= entry["appd_pct"] + 3 * entry["appd_sd_pct"]
    assert [(s["first"], s["count"]) for s in document["sequences"]] == [(0, 4)]


def test_the_parameter_that_moved_most_is_the_one_whose_offset_alone_moves_pixels_most(street: Street):
    from appdgen.cli.detect import appd_per_unit, most_moved
    from appdgen.geometry.appd import appd

    belief = load(street.calib)
    rates = appd_per_unit(belief, None)
    assert set(rates) == set(belief.param_names) and min(rates.values()) > 0
    for name, offset in (("cx", 2.0), ("k1", 0.004)):  # the rate against APPD at the raw size, a step 2-4x larger
        alone = appd(belief, belief.replace(**{name: belief.params()[name] + offset}))[1]
        assert rates[name] * offset == pytest.approx(alone, rel=0.05), name
    offsets = {"fx": {"mean": 3.0, "sd": 0.1}, "cx": {"mean": -2.0, "sd": 1.0}, "k1": {"mean": 0.0, "sd": 1e-9}}
    bigger = max(("fx", 3.0), ("cx", 2.0), key=lambda item: rates[item[0]] * item[1])[0]
    assert most_moved(offsets, rates).split()[0] == bigger and most_moved({}, rates) == ""


def test_the_plot_is_written_and_shows_the_windows(street: Street, tmp_path: Path):
    pytest.importorskip("matplotlib")
    import cv2

    out = tmp_path / "detect.png"
    result = detect(street, "--plot", str(out))
    assert result.exit_code == 0, result.output
    image = cv2.imread(str(out))
    assert image is not None and image.shape[1] >= 800 and image.std() > 10
    # The top panel's window bands are drawn in the verdict's colour: blue for the readings the table calls not
    # miscalibrated (this street under its own file).
    blue = (np.abs(image.astype(int) - (180, 119, 31)).sum(2) < 60).sum()  # tab:blue in BGR
    assert blue > 100
