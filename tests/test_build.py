"""appdgen build (issue #4): the same bytes whatever --jobs or kills, refusals, the sampler, the output format."""
from __future__ import annotations

import json
import random
import shutil
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import pandas as pd
import pyarrow.parquet as pq
import pytest

from appdgen.calib.calibration import PARAMS, Calibration
from appdgen.dataset.layout import BEND_COLUMNS, CROP_COLUMNS, STAGES, member_record
from appdgen.geometry.appd import appd, px_to_pct
from appdgen.geometry.bend import split_warp
from appdgen.geometry.crop import Crop, valid_region
from appdgen.geometry.maps import rectify
from appdgen.sampling.sampler import Sampler
from appdgen.util.atomic import temporary_target
from helpers import (
    Setup,
    assert_killed_build_sound,
    assert_one_line_error,
    assert_same_build,
    assert_shard_complete,
    kill_group,
    kitti_text,
    raw_image,
    run_cli,
    spawn_cli,
    tree_digest,
    write_png,
)

SIZE = (87, 32)  # output size of the sampler checks: KITTI's aspect exactly

# --- the same bytes whatever --jobs or interruptions ------------------------------------------------------------


def test_jobs_1_and_2_write_identical_shards_and_labels(reference_build: Path, loky_build: Path) -> None:
    assert_same_build(loky_build, reference_build)


def _watch_until_first_shard(process: subprocess.Popen, out: Path, setup: Setup, limit: float = 60.0) -> None:
    """Poll --out while the build runs: every name is final or a temporary, every visible shard is complete."""
    final = {"labels.parquet", "build.json", ".parts"}
    deadline = time.monotonic() + limit
    while process.poll() is None and time.monotonic() < deadline:
        names = [p.name for p in out.iterdir()] if out.is_dir() else []
        assert all(n in final or n.startswith("shard-") or temporary_target(n) for n in names), names
        shards = sorted(out.glob("shard-*.tar"))
        for path in shards:
            assert_shard_complete(path, setup)
        if shards:
            return
        time.sleep(0.005)
    raise AssertionError("the build ended (or stalled) before its first shard appeared")


def test_killed_build_resumes_to_identical_bytes(setup: Setup, reference_build: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    process = spawn_cli(setup.args(out, jobs=2), tmp_path / "stderr.txt")
    try:
        _watch_until_first_shard(process, out, setup)
    finally:
        kill_group(process)
    assert (out / ".parts" / "plan.json").is_file() and not (out / "labels.parquet").exists(), "not killed mid-build"
    assert_killed_build_sound(out, setup)
    result = run_cli(setup.args(out, "--resume"))
    assert result.exit_code == 0, result.output
    assert_same_build(out, reference_build)


@pytest.mark.parametrize("change", [["--seed", "8"], ["--samples", "48"], ["--size", "174x64"],
                                    ["--zero-fraction", "0.5"], ["--ranges", "fx=-1%:1%"], ["--format", "npy"]])
def test_resume_with_other_options_is_refused(setup: Setup, interrupted_build: Path, change: list[str]) -> None:
    before = tree_digest(interrupted_build)
    result = run_cli(setup.args(interrupted_build, "--resume", *change))
    assert_one_line_error(result, f"--out {interrupted_build}", "other inputs or options")
    assert tree_digest(interrupted_build) == before


@pytest.mark.parametrize("content", ["reference", "interrupted", "foreign"])
def test_non_empty_out_is_refused_and_untouched(setup: Setup, tmp_path: Path, content: str,
                                                request: pytest.FixtureRequest) -> None:
    out = tmp_path / "foreign" if content == "foreign" else request.getfixturevalue(f"{content}_build")
    if content == "foreign":
        (out / "notes").mkdir(parents=True)
        (out / "notes" / "keep.txt").write_text("mine")
    before = tree_digest(out)
    assert_one_line_error(run_cli(setup.args(out)), f"--out {out}", "not empty", "--resume", "--overwrite")
    if content != "interrupted":
        refusal = "already complete" if content == "reference" else "not an interrupted appdgen build"
        assert_one_line_error(run_cli(setup.args(out, "--resume")), refusal)
    if content == "foreign":
        assert_one_line_error(run_cli(setup.args(out, "--overwrite")), "refuses a folder holding other files")
    assert tree_digest(out) == before


# --- the sampler ------------------------------------------------------------------------------------------------


def test_sampler_estimates_match_full_grid_labels_and_calibrations_are_valid(kitti02: Calibration) -> None:
    sampler = Sampler(kitti02, size=SIZE)
    draws = [sampler.draw(3, i) for i in range(40)]
    assert sum(d.is_reference for d in draws) < 5
    for draw in draws:
        valid_region(draw.calib)  # raises for an invalid calibration
        assert abs(draw.estimate_pct - draw.target_pct) <= 0.01 * sampler.appd_max
        assert abs(appd(kitti02, draw.calib, SIZE)[1] - draw.estimate_pct) <= 0.01 * sampler.appd_max


def test_sampler_draw_does_not_depend_on_order(kitti02: Calibration) -> None:
    def essentials(draw) -> tuple:
        return draw.calib, draw.is_reference, draw.target_pct, draw.estimate_pct, draw.evaluations

    forward = [essentials(Sampler(kitti02, size=SIZE).draw(5, i)) for i in range(12)]
    shuffled = list(range(12))
    random.Random(0).shuffle(shuffled)
    sampler = Sampler(kitti02, size=SIZE)
    other = {}
    for i in shuffled:
        sampler.draw(6, i)  # another seed's draws in between change nothing
        other[i] = essentials(sampler.draw(5, i))
    assert [other[i] for i in range(12)] == forward
    assert essentials(sampler.draw(6, 0)) != forward[0]


# --- the output format ------------------------------------------------------------------------------------------

LABEL_COLUMNS = [
    *[(name, "string") for name in ("key", "shard", "raw_path", "split", "camera", "model")],
    ("sample_index", "int64"), ("is_reference", "bool"),
    *[(name, "double") for name in (*PARAMS, "new_fx", "new_fy", "new_cx", "new_cy")],
    ("width", "int32"), ("height", "int32"), ("appd_px", "double"), ("appd_pct", "double"), ("sha256", "string"),
    *[(name, "double") for name in ("crop_x0", "crop_y0", "crop_x1", "crop_y1")],
    *[(name, "double") for name in ("bend_px", "bend_pct", "shift_x_px", "shift_y_px", "scale")],
]
BUILD_JSON_KEYS = {"appdgen_version", "calibration", "images", "images_sha256", "channels", "max_fov", "samples",
                   "size", "format", "encoder", "shard_size", "seed",
                   "appd_max", "zero_fraction", "interp", "ranges", "command", "counts", "shards", "sampler",
                   "timings", "libraries"}


def test_labels_parquet_schema_and_pandas(reference_build: Path, setup: Setup) -> None:
    path = reference_build / "labels.parquet"
    assert [(f.name, str(f.type)) for f in pq.read_schema(path)] == LABEL_COLUMNS
    frame = pd.read_parquet(path)
    assert len(frame) == setup.samples and list(frame["sample_index"]) == list(range(setup.samples))
    dtypes = {"sample_index": "int64", "is_reference": "bool", "width": "int32", "fx": "float64", "appd_pct": "float64"}
    assert {column: str(frame[column].dtype) for column in dtypes} == dtypes
    assert all(pd.api.types.is_string_dtype(frame[c]) for c in ("key", "split", "camera", "sha256"))


def test_labels_are_the_full_grid_appd_of_the_stored_parameters(reference_build: Path,
                                                                small_camera: Calibration) -> None:
    rows = pq.read_table(reference_build / "labels.parquet").to_pylist()
    for row in rows:
        calib = Calibration(*small_camera.size, *(row[name] for name in PARAMS))
        rect = rectify(calib, SIZE)
        assert (row["width"], row["height"], row["camera"]) == (*SIZE, "02")
        assert [row[k] for k in ("new_fx", "new_fy", "new_cx", "new_cy")] == rect.new_camera_matrix[
            [0, 1, 0, 1], [0, 1, 2, 2]].tolist()
        crop = rect.crop
        assert [row[k] for k in ("crop_x0", "crop_y0", "crop_x1", "crop_y1")] == [crop.x0, crop.y0, crop.x1, crop.y1]
        assert row["appd_px"] == appd(small_camera, calib, SIZE)[0]
        assert row["appd_pct"] == row["appd_px"] * 100 / small_camera.diagonal
        assert (calib == small_camera) == row["is_reference"]


def test_shards_agree_with_labels_and_build_json(reference_build: Path, setup: Setup) -> None:
    rows = pq.read_table(reference_build / "labels.parquet").to_pylist()
    build = json.loads((reference_build / "build.json").read_text())
    assert set(build) == BUILD_JSON_KEYS
    assert (build["samples"], build["size"], build["seed"]) == (setup.samples, [87, 32], setup.seed)
    assert [s["file"] for s in build["shards"]] == [f"shard-{k:06d}.tar" for k in range(setup.shard_count)]
    for entry in build["shards"]:
        mine = [r for r in rows if r["shard"] == entry["file"]]
        assert_shard_complete(reference_build / entry["file"], setup, mine)
        assert entry["samples"] == len(mine) and entry["splits"] == dict(Counter(r["split"] for r in mine))
        assert entry["bytes"] == (reference_build / entry["file"]).stat().st_size
    assert build["counts"]["samples"] == setup.samples and build["counts"]["shards"] == setup.shard_count
    stages, timings = build["timings"]["stage_seconds"], build["timings"]
    assert list(stages) == list(STAGES) and all(v > 0 for v in stages.values())
    assert sum(stages.values()) <= timings["wall_seconds"] * 2  # worker seconds: at most two workers' worth


WEBDATASET_READER = """
import hashlib, json, sys
import cv2, numpy as np, webdataset
for sample in webdataset.WebDataset(sys.argv[1:], shardshuffle=False):
    image = cv2.imdecode(np.frombuffer(sample["png"], np.uint8), cv2.IMREAD_COLOR)
    print(json.dumps({"key": sample["__key__"], "shape": image.shape, "label": json.loads(sample["json"]),
                      "sha256": hashlib.sha256(sample["png"]).hexdigest()}))
assert not [name for name in sys.modules if name.startswith("appdgen")]
"""


def test_shards_read_with_plain_webdataset(reference_build: Path, tmp_path: Path) -> None:
    shards = [str(p) for p in sorted(reference_build.glob("shard-*.tar"))]
    done = subprocess.run([sys.executable, "-c", WEBDATASET_READER, *shards], cwd=tmp_path, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    samples = [json.loads(line) for line in done.stdout.splitlines()]
    rows = pq.read_table(reference_build / "labels.parquet").to_pylist()
    assert [s["key"] for s in samples] == [r["key"] for r in rows]
    for sample, row in zip(samples, rows, strict=True):
        assert sample["shape"] == [32, 87, 3] and sample["sha256"] == row["sha256"]
        assert sample["label"] == member_record(row)
        assert not set(sample["label"]) & {"sha256", *CROP_COLUMNS, *BEND_COLUMNS}  # index-only: members keep bytes


def bend_of_row(row: dict, reference: Calibration) -> dict[str, float]:
    """The bend columns recomputed from a label row's own parameters and crop (split_warp, apart from the build)."""
    calib = reference.replace(**{name: row[name] for name in PARAMS})
    split = split_warp(reference, valid_region(reference), calib, Crop(*(row[name] for name in CROP_COLUMNS)))
    return {"bend_px": split.bend_px, "bend_pct": px_to_pct(split.bend_px, reference), "shift_x_px": split.shift_x_px,
            "shift_y_px": split.shift_y_px, "scale": split.scale}


def test_bend_columns_are_the_split_of_each_rows_own_warp(reference_build: Path, small_camera: Calibration) -> None:
    rows = pq.read_table(reference_build / "labels.parquet").to_pylist()
    drawn = [r for r in rows if not r["is_reference"]]
    assert len(drawn) >= 30
    for row in drawn:
        assert {name: row[name] for name in BEND_COLUMNS} == bend_of_row(row, small_camera)
        assert row["bend_px"] <= 1.05 * row["appd_px"]
        assert row["bend_pct"] == row["bend_px"] * 100 / small_camera.diagonal
    assert len({round(r["bend_pct"], 6) for r in drawn}) == len(drawn)  # a column of its own, not a constant


def test_the_fit_targets_are_label_columns_and_draw_values_alike() -> None:
    from appdgen.dataset.layout import TARGETS
    from appdgen.sampling.sampler import TARGETS as DRAW_TARGETS

    assert tuple(TARGETS) == DRAW_TARGETS and TARGETS == {"appd": "appd_pct", "bend": "bend_pct"}


def test_reference_samples_have_exactly_no_bend(setup: Setup, small_camera: Calibration, tmp_path: Path) -> None:
    rows = _build_rows(Setup(setup.calib, setup.images, samples=8, shard_size=8).args(
        tmp_path / "out", "--zero-fraction", "0.6"))
    references = [r for r in rows if r["is_reference"]]
    assert references and all(r["appd_px"] == 0 for r in references)
    assert all([r[name] for name in BEND_COLUMNS] == [0.0, 0.0, 0.0, 0.0, 1.0] for r in references)
    assert all(r["bend_px"] > 0 for r in rows if not r["is_reference"])


def test_an_interrupted_build_from_before_the_bend_columns_resumes_to_the_same_bytes(
        setup: Setup, interrupted_build: Path, reference_build: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    shutil.copytree(interrupted_build, out)
    fragments = sorted((out / ".parts").glob("*.parquet"))
    assert fragments
    for path in fragments:  # as the build before the bend columns wrote them (its stats in the metadata kept)
        table = pq.read_table(path)
        pq.write_table(table.drop_columns(list(BEND_COLUMNS)), path)
    result = run_cli(setup.args(out, "--resume"))
    assert result.exit_code == 0, result.output
    assert_same_build(out, reference_build)


def test_builds_from_before_the_bend_columns_still_read_and_verify(reference_build: Path, tmp_path: Path) -> None:
    from appdgen.dataset.reader import open_build

    old = tmp_path / "old"
    shutil.copytree(reference_build, old)
    table = pq.read_table(old / "labels.parquet")
    pq.write_table(table.drop_columns(list(BEND_COLUMNS)), old / "labels.parquet")
    build = open_build(old)
    assert build.labels().num_rows == 40 and "bend_px" not in build.labels().column_names
    assert next(build.samples())[2]["appd_pct"] == table["appd_pct"][0].as_py()
    assert run_cli(["verify", str(old)]).exit_code == 0
    pq.write_table(table.drop_columns(["bend_px"]), old / "labels.parquet")  # half the bend: not a known schema
    result = run_cli(["verify", str(old)])
    assert result.exit_code != 0 and "bend_px" in result.output


# --- splits -----------------------------------------------------------------------------------------------------


def _build_rows(args: list[str]) -> list[dict]:
    """Run a build that must succeed and return its label rows."""
    result = run_cli(args)
    assert result.exit_code == 0, result.output
    out = Path(args[args.index("--out") + 1])
    return pq.read_table(out / "labels.parquet").to_pylist()


def test_split_by_day_on_a_kitti_like_tree(small_camera: Calibration, tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    for day, drive in [("2011_09_26", "0001"), ("2011_09_26", "0005"), ("2011_09_28", "0002")]:
        for camera in ("00", "02"):
            write_png(raw / day / f"{day}_drive_{drive}_sync" / f"image_{camera}" / "data" / "0000000000.png",
                      raw_image(small_camera.size, int(drive)))
    calib = tmp_path / "calib_cam_to_cam.txt"
    calib.write_text(kitti_text({"00": small_camera, "02": small_camera}))
    args = Setup(calib, raw / "*" / "*" / "image_02" / "data" / "*.png", samples=12, shard_size=6).args(
        tmp_path / "out", "--split-by", "day")
    rows = _build_rows(args)
    assert {r["camera"] for r in rows} == {"02"}  # chosen from the image_02 folders
    assert all(r["split"] == r["raw_path"].split("/")[-5] for r in rows)
    assert Counter(r["split"] for r in rows) == {"2011_09_26": 8, "2011_09_28": 4}
    build = json.loads((tmp_path / "out" / "build.json").read_text())
    assert build["counts"]["splits"] == {"2011_09_26": 8, "2011_09_28": 4}


def test_list_file_with_split_column(setup: Setup, tmp_path: Path) -> None:
    images = sorted(setup.images.iterdir())
    listing = tmp_path / "list.txt"
    lines = [f"{images[0]} train", "# a comment line", f"{images[1]}   val  # trailing comment", f"{images[2]}"]
    listing.write_text("\n".join(lines) + "\n")
    rows = _build_rows(Setup(setup.calib, listing, samples=9, shard_size=4).args(tmp_path / "out"))
    assert [r["split"] for r in rows] == ["train"] * 3 + ["val"] * 3 + ["all"] * 3
    assert [r["raw_path"] for r in rows[::3]] == [str(p) for p in images]



def test_more_jobs_than_shards_is_said_since_a_shard_is_one_workers_work(setup: Setup, tmp_path: Path) -> None:
    args = [a for a in setup.args(tmp_path / "one", "--shard-size", str(setup.samples), jobs=2) if a != "--quiet"]
    result = run_cli(args)
    assert result.exit_code == 0, result.output
    assert "note: 1 shard(s) for --jobs 2" in result.stderr
    quiet = run_cli(setup.args(tmp_path / "quiet", "--shard-size", str(setup.samples), jobs=2))
    assert quiet.exit_code == 0 and "note:" not in quiet.stderr
