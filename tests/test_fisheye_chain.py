"""A fisheye end to end, small: synth (kb4) → build --max-fov → fit → evaluate → export → predict --calib."""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest

torch = pytest.importorskip("torch")

from helpers import assert_one_line_error, run_cli, shard_members  # noqa: E402
from train import checkpoint  # noqa: E402
from train.cli import main as train_main  # noqa: E402

FIXTURE = Path(__file__).parent / "data" / "calib" / "kalibr_tumvi_like.yaml"
MAX_FOV = 120.0


def train_cli(args: list, capsys) -> str:
    """Run `python -m train ARGS` in-process; returns stdout (SystemExit on errors)."""
    train_main([str(a) for a in args])
    return capsys.readouterr().out


def train_error(args: list, capsys) -> str:
    """Run a train command that must fail; returns its one-line stderr."""
    with pytest.raises(SystemExit) as exc:
        train_main([str(a) for a in args])
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2 and err.count("\n") == 0, err
    return err


@pytest.fixture(scope="module")
def chain(tmp_path_factory) -> Path:
    """raw/ (6 synthetic 128x128 kb4 frames + calibration.yaml), shards/ (40 samples, --max-fov 120), run/ (4 steps)."""
    root = tmp_path_factory.mktemp("fisheye")
    result = run_cli(["synth", "--calib", str(FIXTURE), "--camera", "cam0", "--frames", "6", "--scale", "0.25",
                      "--out", str(root / "raw"), "--jobs", "1", "--quiet"])
    assert result.exit_code == 0, result.output
    result = run_cli(["build", "--calib", str(root / "raw" / "calibration.yaml"), "--images", str(root / "raw"),
                      "--out", str(root / "shards"), "--samples", "40", "--max-fov", str(MAX_FOV), "--jobs", "1",
                      "--quiet"])
    assert result.exit_code == 0, result.output
    train_main(["fit", "--shards", str(root / "shards"), "--run", str(root / "run"), "--split", "all", "--steps", "4",
                "--batch", "8", "--workers", "0", "--val-split", "none", "--quiet"])
    return root


def reference_sample(root: Path) -> tuple[str, np.ndarray]:
    """(raw frame name, decoded BGR image) of the build's reference sample: that frame rectified exactly."""
    row = next(r for r in pq.read_table(root / "shards" / "labels.parquet").to_pylist() if r["is_reference"])
    data = shard_members(root / "shards" / row["shard"])[f"{row['key']}.png"]
    return row["raw_path"], cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)


def test_synth_writes_a_kb4_camera_that_needs_a_fov_bound(chain):
    from appdgen.calib.formats import load

    calib = load(chain / "raw" / "calibration.yaml")
    assert (calib.model, calib.size) == ("kb4", (128, 128))
    assert (calib.fx, calib.cx) == pytest.approx((191.0 * 0.25, (255.0 + 0.5) * 0.25 - 0.5))
    result = run_cli(["build", "--calib", str(chain / "raw" / "calibration.yaml"), "--images", str(chain / "raw"),
                      "--out", str(chain / "unbounded"), "--samples", "4", "--quiet"])
    assert_one_line_error(result, "--max-fov")
    assert not (chain / "unbounded" / "build.json").exists()


def test_build_records_the_bound_and_inspect_verify_and_sheet_cope(chain):
    info = json.loads((chain / "shards" / "build.json").read_text())
    assert info["max_fov"] == MAX_FOV and info["calibration"]["model"] == "kb4"
    labels = pq.read_table(chain / "shards" / "labels.parquet")
    assert set(labels["model"].to_pylist()) == {"kb4"} and {"k1", "k4"} <= set(labels.column_names)
    result = run_cli(["verify", str(chain / "shards")])
    assert result.exit_code == 0 and "OK" in result.output
    result = run_cli(["inspect", str(chain / "shards"), "--sheet", str(chain / "sheet.png")])
    assert result.exit_code == 0, result.output
    assert "kb4 lens" in result.output and "bounded at 120°" in result.output
    sheet = cv2.imread(str(chain / "sheet.png"))
    assert sheet is not None and sheet.shape[0] > 128 and sheet.std() > 10  # real pictures, not a blank canvas


def test_fit_records_the_build_rectification_rule(chain):
    ckpt = checkpoint.load(chain / "run" / "last.pt")
    assert checkpoint.rectify_rule(ckpt) == {"max_fov": MAX_FOV, "interp": "lanczos4"}
    assert json.loads((chain / "run" / "config.json").read_text())["rectify"]["max_fov"] == MAX_FOV


def test_evaluate_runs_on_the_fisheye_build(chain, capsys):
    out = train_cli(["evaluate", "--ckpt", chain / "run" / "last.pt", "--shards", chain / "shards", "--split", "all",
                     "--workers", 0], capsys)
    result = json.loads(out)
    assert result["n"] == 40 and np.isfinite(result["mae"])


def test_export_carries_the_rule(chain, tmp_path, capsys):
    pt2 = tmp_path / "m.pt2"
    assert "ok" in train_cli(["export", "--ckpt", chain / "run" / "last.pt", "--pt2", pt2], capsys)
    extra = {"config.json": ""}
    torch.export.load(str(pt2), extra_files=extra)
    assert json.loads(extra["config.json"])["rectify"] == {"max_fov": MAX_FOV, "interp": "lanczos4"}


def test_predict_rectifies_raw_fisheye_frames_as_the_build_did(chain, capsys):
    from train.predict import rectifier, rectify_rule

    ckpt_path = chain / "run" / "last.pt"
    ckpt = checkpoint.load(ckpt_path)
    frame, sample = reference_sample(chain)
    raw = cv2.imread(str(chain / "raw" / frame))
    prep = rectifier(str(chain / "raw" / "calibration.yaml"), None, (128, 128),
                     rectify_rule(ckpt, str(ckpt_path), None))
    np.testing.assert_array_equal(prep(raw, frame), sample)  # the very pixels the detector was trained on
    out = train_cli(["predict", "--ckpt", ckpt_path, "--calib", chain / "raw" / "calibration.yaml",
                     chain / "raw" / frame, "--json"], capsys)
    predicted = json.loads(out)["predictions"][0]["appd_pct"]
    with torch.no_grad():
        x = torch.from_numpy(sample.transpose(2, 0, 1).copy())[None].float() / 255.0
        expected = float(checkpoint.build_model(ckpt)(x)[0])
    assert predicted == pytest.approx(expected, abs=1e-5)


def test_predict_max_fov_only_fills_in_an_unrecorded_rule(chain, tmp_path, capsys):
    calib, frames = chain / "raw" / "calibration.yaml", chain / "raw"
    ckpt_path = chain / "run" / "last.pt"
    err = train_error(["predict", "--ckpt", ckpt_path, "--calib", calib, frames, "--max-fov", 100], capsys)
    assert "--max-fov 100" in err and "120°" in err
    assert train_error(["predict", "--ckpt", ckpt_path, frames, "--max-fov", 120], capsys).endswith("needs --calib")
    same = train_cli(["predict", "--ckpt", ckpt_path, "--calib", calib, frames, "--max-fov", 120, "--json"], capsys)
    # A checkpoint from before fit recorded the rule: the fisheye is refused unbounded, --max-fov supplies the bound.
    old = checkpoint.load(ckpt_path)
    del old["config"]["rectify"]
    old_path = tmp_path / "old.pt"
    checkpoint.save(old_path, old)
    assert "--max-fov" in train_error(["predict", "--ckpt", old_path, "--calib", calib, frames], capsys)
    filled = train_cli(["predict", "--ckpt", old_path, "--calib", calib, frames, "--max-fov", 120, "--json"], capsys)
    assert json.loads(filled)["predictions"] == json.loads(same)["predictions"]


def test_resume_refuses_and_evaluate_notes_another_crop_rule(chain, tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    state = checkpoint.load(chain / "run" / "last.pt")
    state["config"]["rectify"] = {"max_fov": 100.0, "interp": "lanczos4"}
    checkpoint.save(run / "last.pt", state)
    err = train_error(["fit", "--shards", chain / "shards", "--run", run, "--split", "all", "--steps", 5,
                       "--batch", 8, "--workers", 0, "--val-split", "none", "--resume", "--quiet"], capsys)
    assert "bounded at 100°" in err and "bounded at 120°" in err
    train_main(["evaluate", "--ckpt", str(run / "last.pt"), "--shards", str(chain / "shards"), "--split", "all",
                "--workers", "0"])
    assert "note: the checkpoint was trained on crops bounded at 100°" in capsys.readouterr().err
