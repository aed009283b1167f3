"""open_build: the one reader of a build folder (what train/, inspect, verify and the benchmarks read through)."""
from __future__ import annotations

import json
import shutil
import tarfile
from pathlib import Path

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest

from appdgen.calib.formats import load
from appdgen.dataset.reader import open_build
from appdgen.errors import AppdgenError
from helpers import Setup


def test_a_build_reads_back_as_its_summary_says(reference_build: Path, setup: Setup) -> None:
    build = open_build(reference_build)
    info = json.loads((reference_build / "build.json").read_text())
    assert build.path == reference_build and build.info == info
    assert build.reference == load(setup.calib, "02") and build.model == "radtan"
    assert build.size == (87, 32) and build.image_ext == ".png" and build.max_fov is None
    assert build.interp == info["interp"] == "lanczos4"
    assert build.count == setup.samples and build.splits == {"all": setup.samples}
    assert build.shards == tuple(reference_build / f"shard-{k:06d}.tar" for k in range(setup.shard_count))
    assert build.options["seed"] == setup.seed and build.options["shard_size"] == setup.shard_size
    assert build.labels().equals(pq.read_table(reference_build / "labels.parquet"))
    assert build.labels(columns=["key"]).column_names == ["key"]


def test_samples_are_the_shards_images_with_their_label_rows(reference_build: Path, setup: Setup) -> None:
    build = open_build(reference_build)
    with tarfile.open(reference_build / "shard-000002.tar") as tar:
        member = tar.extractfile("000000017.png").read()
    expected = cv2.imdecode(np.frombuffer(member, np.uint8), cv2.IMREAD_COLOR)
    samples = list(build.samples())
    assert [key for key, _, _ in samples] == [f"{i:09d}" for i in range(setup.samples)]
    key, image, row = samples[17]
    assert np.array_equal(image, expected) and row["key"] == key and row["shard"] == "shard-000002.tar"
    assert row == pq.read_table(reference_build / "labels.parquet").to_pylist()[17]
    assert list(build.samples(split="test")) == [] and build.labels(split="test").num_rows == 0


def test_missing_unfinished_and_foreign_folders_are_refused_naming_them(reference_build: Path,
                                                                        tmp_path: Path) -> None:
    with pytest.raises(AppdgenError, match=f"^{tmp_path / 'nope'}: no such folder$"):
        open_build(tmp_path / "nope")
    with pytest.raises(AppdgenError, match=r"not an appdgen build \(no labels.parquet\)"):
        open_build(tmp_path)
    copy = Path(shutil.copytree(reference_build, tmp_path / "copy"))
    (copy / "build.json").write_text("{}")
    with pytest.raises(AppdgenError, match=f"^{copy}: build.json: not an appdgen build summary"):
        open_build(copy)
    (copy / ".parts").mkdir()
    with pytest.raises(AppdgenError, match=f"^{copy}: build not finished"):
        open_build(copy)
