"""appdgen inspect / verify on a tiny real build: counts, contact sheet, and every kind of damage verify must name."""
from __future__ import annotations

import io
import json
import shutil
import tarfile
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner
from conftest import KITTI_2011_09_26
from hypothesis import given, settings
from hypothesis import strategies as st

from appdgen.calib.calibration import PARAMS
from appdgen.cli import main
from appdgen.dataset.build import build
from appdgen.dataset.inspect import histogram, sheet_layout, spread
from appdgen.dataset.layout import label_schema
from appdgen.dataset.plan import BuildConfig
from appdgen.dataset.verify import verify
from appdgen.sources.frames import RawImage

SAMPLES, SHARD_SIZE, SIZE = 12, 4, (174, 64)  # 3 shards; 174x64 keeps KITTI's 1392:512 aspect

Members = list[tuple[tarfile.TarInfo, bytes]]


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished 12-sample build from two synthetic raw images (one train, one test)."""
    root = tmp_path_factory.mktemp("inspect")
    rng = np.random.default_rng(0)
    images = []
    for split in ("train", "test"):
        raw = cv2.GaussianBlur(rng.integers(0, 256, (512, 1392, 3), dtype=np.uint8), (0, 0), 4)
        cv2.imwrite(str(root / f"{split}.png"), raw)
        images.append(RawImage(root / f"{split}.png", f"{split}.png", split))
    config = BuildConfig(reference=KITTI_2011_09_26["02"], camera="02", calib_path="calib_cam_to_cam.txt",
                         images=tuple(images), samples=SAMPLES, size=SIZE, shard_size=SHARD_SIZE)
    build(config, root / "out", jobs=1, progress=False, command=["test"])
    return root / "out"


@pytest.fixture
def out(built: Path, tmp_path: Path) -> Path:
    """A private copy of the build, free to damage."""
    return Path(shutil.copytree(built, tmp_path / "out"))


def run(*args: str) -> tuple[int, str]:
    """Run the CLI; (exit code, stdout + stderr)."""
    result = CliRunner().invoke(main, [str(a) for a in args])
    return result.exit_code, result.output


def problems(out: Path) -> str:
    """verify's output, asserting it failed with exit 1."""
    code, text = run("verify", out)
    assert code == 1, text
    return text


def members(path: Path) -> Members:
    """Every member of a tar with its bytes."""
    with tarfile.open(path) as tar:
        return [(m, tar.extractfile(m).read() if m.isreg() else b"") for m in tar.getmembers()]


def rewrite(path: Path, change: Callable[[Members], Members]) -> None:
    """Rewrite a shard as USTAR with its members changed by `change`."""
    changed = change(members(path))
    with tarfile.open(path, "w", format=tarfile.USTAR_FORMAT) as tar:
        for info, data in changed:
            tar.addfile(info, io.BytesIO(data) if info.isreg() else None)


def regular(name: str, data: bytes) -> tuple[tarfile.TarInfo, bytes]:
    """A plain-file member."""
    info = tarfile.TarInfo(name)
    info.size = len(data)
    return info, data


def flip(path: Path, offset: int) -> None:
    """Invert the lowest bit of one byte of a file."""
    data = bytearray(path.read_bytes())
    data[offset] ^= 1
    path.write_bytes(bytes(data))


def member_offset(path: Path, name: str) -> int:
    """Byte offset of the middle of a member's data."""
    with tarfile.open(path) as tar:
        member = tar.getmember(name)
        return member.offset_data + member.size // 2


def edit_index(out: Path, change: Callable[[list[dict]], None]) -> None:
    """Rewrite labels.parquet with its rows changed in place by `change`."""
    rows = pq.read_table(out / "labels.parquet").to_pylist()
    change(rows)
    pq.write_table(pa.Table.from_pylist(rows, schema=label_schema(PARAMS)), out / "labels.parquet")


# --- inspect ---------------------------------------------------------------------------------------------------


def test_inspect_prints_the_counts(built: Path) -> None:
    code, text = run("inspect", built)
    assert code == 0, text
    assert f"{SAMPLES} samples in 3 shards, 174x64 png, from 2 raw images (camera 02" in text
    assert "splits: test 6, train 6" in text
    info = json.loads((built / "build.json").read_text())
    assert f"reference samples (exactly the calibration, APPD 0): {info['counts']['references']}" in text
    bars = [line for line in text.splitlines() if line.startswith("  0.") and "–" in line]
    assert len(bars) == 10 and sum(int(line.split()[-1]) for line in bars) == SAMPLES
    assert "APPD evaluations and" in text and "samples/s" in text and "on disk: " in text
    bend = pq.read_table(built / "labels.parquet")["bend_pct"].to_numpy()
    assert f"bend (the non-affine part of APPD): {bend.min():.3f}–{bend.max():.3f} % (mean {bend.mean():.3f} %)" in text


def test_histogram_bins_and_overflow() -> None:
    lines = histogram(np.array([0.0, 0.05, 0.5, 0.99, 1.0, 1.2]), 1.0, bins=4)
    assert "(1 above 1 counted in the last bin)" in lines[0]  # 1.0 itself belongs to the last bin
    assert [int(line.split()[-1]) for line in lines[1:]] == [2, 0, 1, 3]


def test_spread_is_deterministic_and_covers_the_range() -> None:
    pct = np.array([0.5, 0.1, 0.9, 0.1, 0.3, 0.7, 0.0])
    chosen = spread(pct, 4)
    assert list(chosen) == list(spread(pct, 4)) and len(set(chosen)) == 4
    assert pct[chosen[0]] == pct.min() and pct[chosen[-1]] == pct.max()
    assert list(pct[chosen]) == sorted(pct[chosen])
    assert len(spread(pct, 99)) == pct.size


def test_contact_sheet_is_a_png_grid(built: Path, tmp_path: Path) -> None:
    sheet = tmp_path / "sheet.png"
    code, text = run("inspect", built, "--sheet", sheet, "--count", 12)
    assert code == 0, text
    image = cv2.imread(str(sheet))
    # 174x64 samples are enlarged to 288x106 tiles (+22 px caption); 12 of them make 3 columns x 4 rows (about
    # 4:3), with 4 px gaps, under a 26 px title.
    assert sheet_layout(12, *SIZE) == (3, 4, 288, 106)
    assert image.shape == (26 + 4 * (106 + 22 + 4) + 4, 3 * (288 + 4) + 4, 3)
    assert f"wrote {sheet} (880x558)" in text


def test_contact_sheet_of_more_samples_than_the_build(built: Path, tmp_path: Path) -> None:
    code, text = run("inspect", built, "--sheet", tmp_path / "all.png", "--count", 100)
    assert code == 0 and cv2.imread(str(tmp_path / "all.png")) is not None, text


def test_inspect_refuses_an_unfinished_build(out: Path) -> None:
    (out / "labels.parquet").unlink()
    (out / ".parts").mkdir()
    (out / ".parts" / "plan.json").write_text(json.dumps({"samples": SAMPLES, "shard_size": SHARD_SIZE}))
    (out / ".parts" / "shard-000000.tar.parquet").write_bytes(b"")
    for command in ("inspect", "verify"):
        code, text = run(command, out)
        assert code == 2 and text.count("\n") == 1, text
        assert "build not finished (1 of 3 shards done; no labels.parquet yet)" in text and "--resume" in text


@pytest.mark.parametrize("command", ["inspect", "verify"])
def test_missing_or_foreign_folder_exits_2(tmp_path: Path, command: str) -> None:
    code, text = run(command, tmp_path / "nope")
    assert code == 2 and "no such folder" in text and text.count("\n") == 1
    code, text = run(command, tmp_path)
    assert code == 2 and "not an appdgen build (no labels.parquet)" in text


# --- verify ----------------------------------------------------------------------------------------------------


def test_verify_ok_on_a_fresh_build(built: Path) -> None:
    code, text = run("verify", built)
    assert (code, text) == (0, f"verified {SAMPLES} samples in 3 shards: OK\n")


@pytest.mark.parametrize("name", ["000000005.png", "000000005.json", "000000004.json", "000000007.png"])
def test_verify_names_a_member_with_a_flipped_byte(out: Path, name: str) -> None:
    shard = out / "shard-000001.tar"
    flip(shard, member_offset(shard, name))
    text = problems(out)
    assert f"shard-000001.tar: {name}: " in text
    if name.endswith(".png"):
        assert "sha256 differs from labels.parquet" in text


def test_verify_finds_a_flipped_byte_in_a_header(out: Path) -> None:
    shard = out / "shard-000001.tar"
    with tarfile.open(shard) as tar:
        header = tar.getmember("000000006.json").offset
    flip(shard, header + 100)  # the mode field: tarfile's checksum fails and it stops reading there
    text = problems(out)
    assert "shard-000001.tar: after 000000005.png: non-zero bytes at" in text
    assert "shard-000001.tar: 000000006.json: missing" in text


@settings(max_examples=60, deadline=None, database=None)
@given(where=st.floats(0, 1, exclude_max=True), bit=st.integers(0, 7))
def test_verify_finds_any_flipped_bit(built: Path, tmp_path_factory: pytest.TempPathFactory, where: float,
                                      bit: int) -> None:
    out = Path(shutil.copytree(built, tmp_path_factory.mktemp("flip") / "out"))
    shard = out / "shard-000002.tar"
    data = bytearray(shard.read_bytes())
    data[int(where * len(data))] ^= 1 << bit
    shard.write_bytes(bytes(data))
    assert not verify(out).ok


@pytest.mark.parametrize("cut", ["mid-member", "at-a-header", "end-blocks", "padding"])
def test_verify_detects_a_truncated_shard(out: Path, cut: str) -> None:
    shard = out / "shard-000002.tar"
    with tarfile.open(shard) as tar:
        last = tar.getmembers()[-1]
        header = tar.getmember("000000010.json").offset
    end = last.offset_data + -(-last.size // 512) * 512
    size = {"mid-member": member_offset(shard, "000000009.png"), "at-a-header": header, "end-blocks": end + 512,
            "padding": shard.stat().st_size - 512}[cut]
    with shard.open("r+b") as stream:
        stream.truncate(size)
    text = problems(out)
    assert "shard-000002.tar: " in text
    assert {"mid-member": "000000009.png: truncated", "at-a-header": "000000010.json: missing",
            "end-blocks": "truncated: ", "padding": "not a whole number of 10240-byte tar records"}[cut] in text


def test_verify_detects_a_deleted_shard(out: Path) -> None:
    (out / "shard-000001.tar").unlink()
    text = problems(out)
    assert f"shard-000001.tar: missing ({SHARD_SIZE} samples of labels.parquet are in it)" in text


def test_verify_detects_a_stray_shard_file(out: Path) -> None:
    shutil.copy(out / "shard-000000.tar", out / "shard-000007.tar")
    assert "shard-000007.tar: shard file not named in labels.parquet" in problems(out)


def test_verify_detects_an_extra_member(out: Path) -> None:
    rewrite(out / "shard-000000.tar", lambda ms: ms + [regular("000000003.txt", b"hello")])
    assert "shard-000000.tar: 000000003.txt: unexpected member" in problems(out)


def test_verify_refuses_a_dotdot_member(out: Path) -> None:
    rewrite(out / "shard-000000.tar", lambda ms: ms[:2] + [regular("../000000001.png", ms[3][1])] + ms[2:])
    assert "shard-000000.tar: ../000000001.png: unsafe name (absolute or with '..')" in problems(out)


def test_verify_refuses_an_absolute_member(out: Path) -> None:
    rewrite(out / "shard-000000.tar", lambda ms: ms + [regular("/tmp/000000001.png", b"x")])
    assert "shard-000000.tar: /tmp/000000001.png: unsafe name" in problems(out)


def test_verify_refuses_a_symlink_member(out: Path) -> None:
    def to_link(ms: Members) -> Members:
        link = tarfile.TarInfo("000000001.png")
        link.type, link.linkname = tarfile.SYMTYPE, "/etc/passwd"
        return ms[:3] + [(link, b"")] + ms[4:]

    rewrite(out / "shard-000000.tar", to_link)
    text = problems(out)
    assert "shard-000000.tar: 000000001.png: symbolic link to '/etc/passwd': only plain files" in text
    assert "000000001.png: missing" not in text  # one line per member


def test_verify_detects_members_out_of_order(out: Path) -> None:
    rewrite(out / "shard-000000.tar", lambda ms: [ms[1], ms[0], *ms[2:]])
    assert "shard-000000.tar: 000000000.png: out of order" in problems(out)


def test_verify_detects_a_duplicate_member(out: Path) -> None:
    rewrite(out / "shard-000000.tar", lambda ms: ms + [ms[0]])
    assert "shard-000000.tar: 000000000.json: duplicate member" in problems(out)


def test_verify_detects_a_changed_index_row(out: Path) -> None:
    def change(rows: list[dict]) -> None:
        rows[5]["appd_pct"] += 0.01
        rows[9]["sha256"] = "0" * 64
        rows[2]["raw_path"] = "other.png"

    edit_index(out, change)
    text = problems(out)
    assert "shard-000001.tar: 000000005.json: appd_pct is " in text
    assert "shard-000002.tar: 000000009.png: sha256 differs from labels.parquet" in text
    assert "shard-000000.tar: 000000002.json: raw_path is 'test.png' here, 'other.png' in labels.parquet" in text \
        or "shard-000000.tar: 000000002.json: raw_path is 'train.png' here, 'other.png' in labels.parquet" in text


def test_verify_reports_empty_index_values(out: Path) -> None:
    edit_index(out, lambda rows: rows[3].update(key=None, sha256=None))
    assert "labels.parquet: empty values in key (1), sha256 (1)" in problems(out)


def test_verify_refuses_a_made_up_shard_path(out: Path) -> None:
    edit_index(out, lambda rows: rows[0].update(shard="../shard-000000.tar"))
    text = problems(out)
    assert "labels.parquet: shard '../shard-000000.tar' is not a shard file name" in text
    assert "labels.parquet: sample 000000000 is listed in ../shard-000000.tar, its shard is shard-000000.tar" in text


def test_verify_detects_a_dropped_index_row(out: Path) -> None:
    edit_index(out, lambda rows: rows.pop(6))
    text = problems(out)
    assert "build.json: counts.samples is 12, labels.parquet has 11" in text
    assert "shard-000001.tar: 000000006.json: unexpected member" in text


def test_verify_checks_build_json_counts(out: Path) -> None:
    info = json.loads((out / "build.json").read_text())
    info["counts"]["splits"] = {"train": 12}
    info["shards"][0]["bytes"] += 1
    (out / "build.json").write_text(json.dumps(info))
    text = problems(out)
    assert "build.json: counts.splits is {'train': 12}, labels.parquet has {'test': 6, 'train': 6}" in text
    assert "build.json: shard-000000.tar: " in text and "bytes, the file has" in text


@pytest.mark.parametrize("name", ["labels.parquet", "build.json"])
def test_verify_reports_a_damaged_index_or_summary(out: Path, name: str) -> None:
    (out / name).write_bytes(b"garbage")
    code, text = run("verify", out)
    assert code == 1 and text.startswith(f"{name}: unreadable"), text


def test_verify_caps_its_output_at_20_lines(out: Path) -> None:
    def change(rows: list[dict]) -> None:
        for row in rows:
            row["appd_pct"] += 1.0
            row["sha256"] = "f" * 64

    edit_index(out, change)
    text = problems(out).splitlines()
    assert len(text) == 22 and text[20] == "… and 4 more"
    assert text[21] == f"verify failed: 24 problems in {SAMPLES} samples in 3 shards ({out})"


def test_inspect_and_verify_read_the_lens_model_from_build_json(built: Path, out: Path) -> None:
    code, text = run("inspect", built)
    assert "radtan lens" in text
    assert pq.read_table(built / "labels.parquet").column("model").to_pylist() == ["radtan"] * SAMPLES
    info = json.loads((out / "build.json").read_text())
    info["calibration"]["model"] = "fisheye9"
    (out / "build.json").write_text(json.dumps(info))
    code, text = run("verify", out)
    assert code == 1 and text.startswith("build.json: lens model 'fisheye9' is not supported"), text
    code, text = run("inspect", out)
    assert code == 2 and "build.json: lens model 'fisheye9' is not supported" in text


def test_verify_reports_an_index_of_another_schema(out: Path) -> None:
    pq.write_table(pq.read_table(out / "labels.parquet").drop_columns(["model"]), out / "labels.parquet")
    code, text = run("verify", out)
    assert code == 1 and text.startswith("labels.parquet: columns differ from appdgen's label schema (missing model)")
