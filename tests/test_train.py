"""The torch trainer (train/): data splitting, model, fit/resume, evaluate, predict, export."""
from __future__ import annotations

import csv
import importlib.util
import json
import shutil
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import cv2  # noqa: E402

from appdgen.dataset.shardset import open_shards, read_labels  # noqa: E402
from appdgen.errors import AppdgenError  # noqa: E402
from synthetic_shards import write_shards  # noqa: E402
from train.checkpoint import check_plain  # noqa: E402
from train.cli import main  # noqa: E402
from train.data import Selection, ShardStream, StreamSpec, count_selected, make_loader, shard_mode_ok  # noqa: E402
from train.errors import TrainError  # noqa: E402
from train.holdout import held_out, holdout_group, holdout_unit  # noqa: E402
from train.model import AppdNet, ModelConfig, check_size  # noqa: E402
from train.predict import RunningVerdict  # noqa: E402

STEPS = 30


def run_cli(args: list[str], capsys) -> str:
    """Run `python -m train ARGS` in-process; returns stdout (raises SystemExit on errors)."""
    main([str(a) for a in args])
    return capsys.readouterr().out


@pytest.fixture(scope="module")
def shards(tmp_path_factory) -> Path:
    """96 samples, 128x128 PNG, 12 per shard, train:test 3:1 by raw image; label from brightness."""
    return write_shards(tmp_path_factory.mktemp("shards"), n=96, per_shard=12)


@pytest.fixture(scope="module")
def trained(shards, tmp_path_factory) -> Path:
    """A run folder after a short fit (with a raw-image holdout for validation)."""
    run = tmp_path_factory.mktemp("runs") / "tiny"
    main(["fit", "--shards", str(shards), "--run", str(run), "--steps", str(STEPS), "--batch", "8", "--lr", "1e-3",
          "--ckpt-every", "15", "--log-every", "5", "--workers", "0", "--val-fraction", "0.2", "--quiet"])
    return run


def keys_of(spec: StreamSpec, workers: int) -> list[str]:
    """Every key one rank's DataLoader yields."""
    return [k for batch in make_loader(spec, 5, workers) for k in batch["key"]]


# --- model ------------------------------------------------------------------------------------------


def test_model_is_the_papers_cnn():
    model = AppdNet(ModelConfig(348, 128))
    convs = [m for m in model.features.modules() if isinstance(m, torch.nn.Conv2d)]
    assert [c.out_channels for c in convs[1::2]] == [32, 32, 32, 64, 128, 128, 128]
    assert all(c.kernel_size == (3, 3) for c in convs) and len(convs) == 14
    pools = [m for m in model.features.modules() if isinstance(m, torch.nn.MaxPool2d)]
    assert len(pools) == 7
    dense = [m for m in model.head if isinstance(m, torch.nn.Linear)]
    # 348x128 → 2x1 after 7 halvings: flatten gives 128·2·1 inputs to dense 512, 128, 1.
    assert [(d.in_features, d.out_features) for d in dense] == [(256, 512), (512, 128), (128, 1)]
    assert any(isinstance(m, torch.nn.Dropout) and m.p == 0.5 for m in model.head)
    assert all(float(c.bias.detach().abs().max()) == 0 for c in convs)
    assert model(torch.rand(2, 3, 128, 348)).shape == (2,)


def test_initial_signal_survives_the_sixteen_layers():
    # Plain Xavier halves the variance at each ReLU (output std ~2e-4 of the input's): the net then sat at the
    # mean predictor. With the ReLU gain the last block's activations stay of order one.
    torch.manual_seed(0)
    model = AppdNet(ModelConfig(348, 128)).eval()
    with torch.no_grad():
        features = model.features(model.normalize(torch.rand(8, 3, 128, 348)))
        outputs = model(torch.rand(8, 3, 128, 348))
    assert 0.3 < float(features.std()) < 3.0
    assert float(outputs.std()) > 1e-2


@pytest.mark.parametrize("size", [(128, 64), (100, 200), (127, 128)])
def test_too_small_images_are_refused_clearly(size):
    with pytest.raises(TrainError, match=r"at least 128x128"):
        check_size(*size)


def test_fit_refuses_shards_too_small_for_the_network(tmp_path, capsys):
    small = write_shards(tmp_path / "small", n=8, size=(128, 64), per_shard=8)
    with pytest.raises(SystemExit) as exc:
        main(["fit", "--shards", str(small), "--run", str(tmp_path / "r"), "--steps", "1"])
    assert exc.value.code == 2
    assert "128x64" in capsys.readouterr().err


def test_fit_trains_on_the_only_split_of_a_build_without_a_train_split(tmp_path, capsys):
    # `appdgen build` without --split-by puts every sample in split 'all': fit takes it, holding out validation.
    root = write_shards(tmp_path / "all", n=32, per_shard=8, splits=(("all", 1),))
    run = tmp_path / "run"
    main(["fit", "--shards", str(root), "--run", str(run), "--steps", "2", "--batch", "4", "--workers", "0",
          "--stats-samples", "8", "--quiet"])
    out, err = capsys.readouterr()
    assert json.loads(out.splitlines()[-1])["step"] == 2
    assert f"fit: {root} has no split 'train'; training on its only split 'all' (32 samples)" in err
    data = json.loads((run / "config.json").read_text())["data"]
    assert data["train"].startswith("split=all, train side of a 10% holdout") and data["n_val"] > 0
    assert data["n_train"] + data["n_val"] == 32
    with pytest.raises(SystemExit):  # a split asked for by name that the build lacks is still an error
        main(["fit", "--shards", str(write_shards(tmp_path / "two", n=16, per_shard=8)), "--run",
              str(tmp_path / "r2"), "--split", "val", "--steps", "1", "--quiet"])
    assert "no samples of split 'val'" in capsys.readouterr().err


# --- data -------------------------------------------------------------------------------------------


@pytest.mark.parametrize("fmt", ["png", "jpg", "npy"])
def test_all_image_formats_decode(tmp_path, fmt):
    root = write_shards(tmp_path, n=4, per_shard=4, fmt=fmt, splits=(("train", 1),))
    samples = list(ShardStream(StreamSpec(open_shards(root).shards, Selection("train"), (128, 128))))
    assert len(samples) == 4
    assert all(s["image"].shape == (3, 128, 128) and s["image"].dtype == torch.uint8 for s in samples)


def test_shards_without_build_json_are_found_by_name(shards, tmp_path):
    copy = shutil.copytree(shards, tmp_path / "copy")
    (copy / "build.json").unlink()
    ss = open_shards(copy)
    assert len(ss.shards) == 8 and ss.size is None
    assert len(list(ShardStream(StreamSpec(ss.shards, Selection("test"))))) == 24


def test_a_missing_shard_is_reported(shards, tmp_path):
    copy = shutil.copytree(shards, tmp_path / "copy")
    (copy / "shard-000003.tar").unlink()
    with pytest.raises(AppdgenError, match="shard-000003.tar"):
        open_shards(copy)


def test_shard_mode_needs_balanced_slots():
    assert shard_mode_ok([8, 8, 8, 8], 2) and shard_mode_ok([8, 8, 8, 8], 4)
    assert not shard_mode_ok([8, 4, 8, 4], 2)  # whole shards would skew sampling frequency
    assert not shard_mode_ok([8, 8], 4)  # fewer shards than slots
    assert shard_mode_ok([3], 1)


@pytest.mark.parametrize("uniform", [True, False], ids=["shard-mode", "sample-mode"])
@pytest.mark.parametrize("world,workers", [(1, 0), (1, 2), (2, 0), (3, 2)])
def test_ranks_and_workers_partition_the_split(tmp_path, uniform, world, workers):
    splits = (("train", 1),) if uniform else (("train", 3), ("test", 1))
    ss = open_shards(write_shards(tmp_path, n=48, per_shard=6, splits=splits))
    sel = Selection("train")
    keys = Counter(k for rank in range(world)
                   for k in keys_of(StreamSpec(ss.for_split("train"), sel, ss.size, rank=rank, world=world), workers))
    assert set(keys.values()) == {1}, "a sample was yielded twice"
    assert sum(keys.values()) == ss.split_count("train"), "a sample was lost"


def test_looping_stream_yields_each_sample_once_per_pass(shards):
    ss = open_shards(shards)
    n = ss.split_count("train")
    stream = iter(ShardStream(StreamSpec(ss.for_split("train"), Selection("train"), ss.size, loop=True,
                                         shuffle=True, buffer=7)))
    first, second = ([next(stream)["key"] for _ in range(n)] for _ in range(2))
    assert len(set(first)) == n and set(first) == set(second) and first != second


@pytest.mark.parametrize("by", ["image", "recording"])
def test_holdout_keeps_raw_images_or_recordings_whole(shards, by):
    labels = read_labels(shards)
    raw = dict(zip(labels["key"], labels["raw_path"], strict=True))
    held = held_out({holdout_group(r) for r in raw.values()}, 0.3) if by == "recording" else None
    tr, va = (Selection("train", 0.3, side, raw, by, held) for side in ("train", "val"))
    side = {k: (tr.accepts({"key": k, "split": s}), va.accepts({"key": k, "split": s}))
            for k, s in zip(labels["key"], labels["split"], strict=True) if s == "train"}
    assert all(a != b for a, b in side.values()), "every training sample is on exactly one side"
    unit = (lambda k: raw[k]) if by == "image" else (lambda k: raw[k].rsplit("/", 1)[0])  # synthetic: raw/recN/x
    by_unit: dict[str, set] = {}
    for k, sides in side.items():
        by_unit.setdefault(unit(k), set()).add(sides)
    assert all(len(s) == 1 for s in by_unit.values()), f"a {by} straddles train and val"
    assert count_selected(labels, tr) + count_selected(labels, va) == len(side)
    assert count_selected(labels, va) > 0 and count_selected(labels, tr) > 0


def test_holdout_group_is_the_kitti_drive_else_the_folder():
    assert holdout_group("2011_09_26/2011_09_26_drive_0001_sync/image_02/data/0000000000.png") == \
        "2011_09_26_drive_0001"
    assert holdout_group("/k/2011_09_26_drive_0005_sync/image_02/data/7.png") == "2011_09_26_drive_0005"
    assert holdout_group("synth/train/frame_000001.png") == "synth/train"


def test_holdout_by_recording_falls_back_to_image_in_a_one_folder_split(capsys):
    labels = {"key": ["a", "b"], "split": ["train", "train"], "raw_path": ["raw/x/1.png", "raw/x/2.png"]}
    assert holdout_unit(labels, "train", "recording", 0.1) == ("image", None)
    assert "one recording" in capsys.readouterr().err
    labels["raw_path"][1] = "raw/y/2.png"
    by, held = holdout_unit(labels, "train", "recording", 0.01)
    assert by == "recording" and len(held) == 1  # at least one recording, never all


def test_held_out_recordings_are_a_fraction_never_none_nor_all():
    names = {f"drive_{i:04d}" for i in range(20)}
    assert len(held_out(names, 0.1)) == 2 and held_out(names, 0.1) <= names
    assert len(held_out(names, 1e-6)) == 1 and len(held_out(names, 0.999)) == 19
    assert held_out(names, 0.3) >= held_out(names, 0.1)  # a larger fraction adds recordings


@pytest.mark.parametrize("workers", [0, 2])
def test_skipping_batches_resumes_the_stream_exactly(shards, workers):
    ss = open_shards(shards)

    def keys(skip: int) -> list[str]:
        spec = StreamSpec(ss.for_split("train"), Selection("train"), ss.size, loop=True, shuffle=True, buffer=7,
                          skip_batches=skip, batch=5)
        batches = iter(make_loader(spec, 5, workers))
        return [k for _ in range(40 - skip) for k in next(batches)["key"]]  # 200 samples: past the 72-sample pass

    whole = keys(0)
    assert keys(13) == whole[13 * 5:]


# --- fit, checkpoints, resume -----------------------------------------------------------------------


def read_log(run: Path) -> list[dict]:
    with open(run / "log.csv") as fh:
        return list(csv.DictReader(fh))


def test_fit_lowers_the_loss_and_beats_the_mean(trained, shards, capsys):
    rows = read_log(trained)
    assert list(rows[0]) == ["step", "train_loss", "val_loss", "val_mae", "lr", "images_per_s"]
    assert float(rows[-1]["train_loss"]) < 0.5 * float(rows[0]["train_loss"])
    assert any(r["val_mae"] for r in rows) and (trained / "best.pt").exists()
    args = ["evaluate", "--ckpt", trained / "last.pt", "--shards", shards, "--workers", 0]
    result = json.loads(run_cli(args, capsys))
    assert result["mae"] < result["mean_predictor_mae"]


def test_checkpoints_load_weights_only(trained):
    for name in ("last.pt", "best.pt"):
        ckpt = torch.load(trained / name, map_location="cpu", weights_only=True)
        assert ckpt["step"] <= STEPS and ckpt["config"]["model"]["width"] == 128
        assert len(ckpt["config"]["model"]["mean"]) == 3 and isinstance(ckpt["config"]["label_mean"], float)
    with pytest.raises(TypeError, match="weights_only"):
        check_plain({"v": torch.__version__})  # a str subclass torch.load would refuse


def test_resume_continues_and_refuses_to_overwrite(trained, shards, tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(trained, run)
    args = ["fit", "--shards", shards, "--run", run, "--steps", STEPS + 5, "--batch", 8, "--workers", 0, "--quiet"]
    with pytest.raises(SystemExit):
        run_cli(args, capsys)
    assert "--resume" in capsys.readouterr().err
    summary = json.loads(run_cli([*args, "--resume"], capsys))
    assert summary["step"] == STEPS + 5
    assert torch.load(run / "last.pt", weights_only=True)["step"] == STEPS + 5
    assert read_log(run)[-1]["step"] == str(STEPS + 5)


def test_epochs_count_steps_from_the_split(shards, tmp_path, capsys):
    summary = json.loads(run_cli(["fit", "--shards", shards, "--run", tmp_path / "r", "--epochs", "0.1",
                                  "--batch", 4, "--workers", 0, "--val-split", "none", "--quiet"], capsys))
    assert summary["step"] == 2  # ceil(0.1 · 72 train samples / 4)


def test_max_minutes_stops_early_with_a_checkpoint(shards, tmp_path, capsys):
    summary = json.loads(run_cli(["fit", "--shards", shards, "--run", tmp_path / "r", "--steps", 1000, "--batch", 4,
                                  "--max-minutes", "1e-6", "--log-every", 2, "--workers", 0, "--quiet"], capsys))
    assert summary["step"] == 2
    assert torch.load(tmp_path / "r" / "last.pt", weights_only=True)["step"] == 2


# --- evaluate, predict, export ----------------------------------------------------------------------


def test_evaluate_reports_bins_and_classification(trained, shards, tmp_path, capsys):
    out = tmp_path / "eval.json"
    plot = tmp_path / "eval.png"
    drawn = importlib.util.find_spec("matplotlib") is not None  # else --plot is refused before evaluating
    main([str(a) for a in ["evaluate", "--ckpt", trained / "last.pt", "--shards", shards, "--split", "test",
                           "--json", out, "--threshold", "1.5", "--workers", 0, *(["--plot", plot] if drawn else [])]])
    stdout, stderr = capsys.readouterr()
    result = json.loads(stdout)
    ratio = result["mae"] / result["mean_predictor_mae"]
    assert (f"test MAE {result['mae']:.3f} % vs mean-predictor MAE {result['mean_predictor_mae']:.3f} % "
            f"(ratio {ratio:.2f}) on 24 images") in stderr
    assert json.loads(out.read_text()) == {k: v for k, v in result.items() if k != "plot"}
    assert result["n"] == 24 and len(result["bins"]) == 10 and result["bins"][-1]["hi"] == 3.0
    assert sum(b["n"] for b in result["bins"]) == 24
    assert {"mae", "rmse", "mean_predictor_mae"} <= set(result)
    cls = result["classification"]
    assert cls["threshold"] == 1.5 and cls["tp"] + cls["fp"] + cls["fn"] + cls["tn"] == 24
    if drawn:
        assert result["plot"] == str(plot) and plot.stat().st_size > 1000


def extract_pngs(shards: Path, dest: Path, n: int = 10) -> list[Path]:
    """The first n test images of the shards as plain PNG files (a 'sequence')."""
    ss = open_shards(shards)
    dest.mkdir()
    paths = []
    for s in ShardStream(StreamSpec(ss.for_split("test"), Selection("test"), ss.size, limit=n)):
        paths.append(dest / f"{s['key']}.png")
        cv2.imwrite(str(paths[-1]), s["image"].numpy().transpose(1, 2, 0))
    return paths


def test_predict_a_folder_as_csv_and_json(trained, shards, tmp_path, capsys):
    extract_pngs(shards, tmp_path / "seq")
    rows = list(csv.DictReader(run_cli(["predict", "--ckpt", trained / "last.pt", tmp_path / "seq", "--csv"],
                                       capsys).splitlines()))
    assert len(rows) == 10 and list(rows[0]) == ["path", "appd_pct", "running_median", "recalibrate"]
    out = json.loads(run_cli(["predict", "--ckpt", trained / "last.pt", tmp_path / "seq", "--json", "--window", 3,
                              "--threshold", "-1"], capsys))
    assert out["summary"]["verdict"] == "recalibrate" and out["summary"]["images"] == 10


def test_predict_reads_globs_and_list_files_as_build_does_and_names_a_bad_path(trained, shards, tmp_path, capsys):
    # predict lists its inputs through appdgen.sources, as build's --images: a glob, a list file (paths relative to
    # it, in its order), and the sources' one-line error for a path that is none of them.
    paths = extract_pngs(shards, tmp_path / "seq", n=4)
    ckpt = trained / "last.pt"
    by_glob = json.loads(run_cli(["predict", "--ckpt", ckpt, tmp_path / "seq" / "*.png", "--json"], capsys))
    listing = tmp_path / "frames.txt"
    listing.write_text("".join(f"seq/{p.name}\n" for p in reversed(paths)))
    by_list = json.loads(run_cli(["predict", "--ckpt", ckpt, listing, "--json"], capsys))
    assert [p["path"] for p in by_glob["predictions"]] == [str(p) for p in sorted(paths)]
    assert [p["path"] for p in by_list["predictions"]] == [str(p) for p in reversed(paths)]
    assert {p["path"]: p["appd_pct"] for p in by_glob["predictions"]} == \
        {p["path"]: p["appd_pct"] for p in by_list["predictions"]}
    with pytest.raises(SystemExit) as exc:
        run_cli(["predict", "--ckpt", ckpt, tmp_path / "nowhere"], capsys)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.count("\n") == 1
    assert f"{tmp_path / 'nowhere'}: no such folder, list file or glob pattern" in err


def test_python_m_train_runs_from_the_repository_root():
    # The trainer is a folder of the repository, not an installed package: `python -m train` from its root.
    import subprocess

    root = Path(__file__).resolve().parents[1]
    helps = {}
    for module in ("train", "studies.experiment", "studies.detector"):
        done = subprocess.run([sys.executable, "-m", module, "--help"], cwd=root, capture_output=True, text=True)
        assert done.returncode == 0, (module, done.stderr)
        helps[module] = done.stdout
    assert all(f"  {command} " in helps["train"] for command in ("fit", "evaluate", "predict", "export"))
    assert "--tiny" in helps["studies.experiment"] and "--arms" in helps["studies.detector"]


def test_predict_names_a_corrupt_jpeg_or_skips_and_counts_it(trained, shards, tmp_path, capsys):
    paths = extract_pngs(shards, tmp_path / "seq", n=4)
    data = bytearray(cv2.imencode(".jpg", cv2.imread(str(paths[1])), [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes())
    middle = len(data) // 2  # 200 body bytes overwritten: OpenCV decodes it (grey rows), libjpeg only warns
    data[middle:middle + 200] = np.random.default_rng(0).integers(0, 256, 200, dtype=np.uint8).tobytes()
    bad = paths[1].with_suffix(".jpg")
    bad.write_bytes(bytes(data))
    paths[1].unlink()
    with pytest.raises(SystemExit):
        run_cli(["predict", "--ckpt", trained / "last.pt", tmp_path / "seq"], capsys)
    err = capsys.readouterr().err
    assert str(bad) in err and "corrupt JPEG" in err
    out = json.loads(run_cli(["predict", "--ckpt", trained / "last.pt", tmp_path / "seq", "--json", "--skip-bad"],
                             capsys))
    assert out["summary"]["images"] == 3 and out["summary"]["skipped_frames"] == 1


def test_predict_refuses_wrong_size_without_calib(trained, tmp_path, capsys):
    cv2.imwrite(str(tmp_path / "big.png"), np.zeros((150, 200, 3), np.uint8))
    with pytest.raises(SystemExit):
        run_cli(["predict", "--ckpt", trained / "last.pt", tmp_path / "big.png"], capsys)
    assert "--calib" in capsys.readouterr().err
    assert "big.png" in run_cli(["predict", "--ckpt", trained / "last.pt", tmp_path / "big.png", "--resize"], capsys)


def test_running_median_verdict():
    verdicts = RunningVerdict(3, 1.0)
    preds = [verdicts.add(str(i), v) for i, v in enumerate([0.1, 3.0, 0.2, 3.0, 3.0])]
    assert [p.running_median for p in preds] == [0.1, 1.55, 0.2, 3.0, 3.0]
    assert [p.recalibrate for p in preds] == [False, True, False, True, True]


def test_predict_with_calib_rectifies_raw_images(trained, tmp_path, capsys):
    from appdgen import Calibration
    from appdgen.calib.formats import save

    # A square raw camera (the network input is 128x128), rectified by appdgen itself before the model sees it.
    save(Calibration(256, 256, 200.0, 200.0, 127.5, 127.5, -0.1, 0.01), tmp_path / "calib.yaml")
    raw = tmp_path / "raw.png"
    cv2.imwrite(str(raw), np.full((256, 256, 3), 90, np.uint8))
    out = run_cli(["predict", "--ckpt", trained / "last.pt", "--calib", tmp_path / "calib.yaml", raw, "--json"],
                  capsys)
    assert len(json.loads(out)["predictions"]) == 1
    cv2.imwrite(str(raw), np.full((100, 256, 3), 90, np.uint8))
    with pytest.raises(SystemExit) as exc:
        run_cli(["predict", "--ckpt", trained / "last.pt", "--calib", tmp_path / "calib.yaml", raw], capsys)
    assert exc.value.code == 2 and "256x256" in capsys.readouterr().err


def test_predict_calib_without_appdgen_support_is_a_clear_error(trained, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "appdgen.calib.formats", None)
    with pytest.raises(SystemExit) as exc:
        run_cli(["predict", "--ckpt", trained / "last.pt", "--calib", "x.yaml", tmp_path], capsys)
    assert exc.value.code == 2 and "appdgen" in capsys.readouterr().err


def test_export_pt2_and_onnx_match_eager(trained, tmp_path, capsys):
    pt2 = tmp_path / "m.pt2"
    out = run_cli(["export", "--ckpt", trained / "last.pt", "--pt2", pt2], capsys)
    assert "ok" in out and pt2.exists()
    extra = {"config.json": ""}
    program = torch.export.load(str(pt2), extra_files=extra)
    assert json.loads(extra["config.json"])["width"] == 128
    model = AppdNet(ModelConfig(128, 128))
    model.load_state_dict(torch.load(trained / "last.pt", weights_only=True)["model"])
    x = torch.rand(5, 3, 128, 128)  # a batch size the export never saw
    torch.testing.assert_close(program.module()(x), model.eval()(x), atol=1e-4, rtol=0)
    pytest.importorskip("onnxscript")
    out = run_cli(["export", "--ckpt", trained / "last.pt", "--onnx", tmp_path / "m.onnx"], capsys)
    assert "tolerance" in out and (tmp_path / "m.onnx").exists()


def test_cli_errors_are_one_line_exit_2(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["fit", "--shards", str(tmp_path / "nope"), "--run", str(tmp_path / "r"), "--steps", "1"])
    assert exc.value.code == 2
    assert capsys.readouterr().err.strip().count("\n") == 0


def test_pixel_normalisation_subtracts_the_mean_training_image(shards, tmp_path, capsys):
    run_cli(["fit", "--shards", shards, "--run", tmp_path / "r", "--steps", 1, "--batch", 4, "--workers", 0,
             "--val-split", "none", "--normalize", "pixel", "--quiet"], capsys)
    ckpt = torch.load(tmp_path / "r" / "last.pt", weights_only=True)
    ss = open_shards(shards)
    images = [s["image"].numpy() / 255.0 for s in ShardStream(StreamSpec(ss.for_split("train"), Selection("train")))]
    mean_image = np.mean(images, axis=0)
    np.testing.assert_allclose(ckpt["model"]["normalize.mean"][0].numpy(), mean_image, atol=1e-5)
    np.testing.assert_allclose(ckpt["model"]["normalize.std"].flatten().numpy(),
                               np.std(images, axis=(0, 2, 3)), rtol=1e-4)
    assert ckpt["config"]["model"]["normalize"] == "pixel"
    out = run_cli(["evaluate", "--ckpt", tmp_path / "r" / "last.pt", "--shards", shards, "--workers", 0], capsys)
    assert json.loads(out)["n"] == ss.split_count("test")  # the checkpoint rebuilds its 1×3×H×W mean buffer


@pytest.mark.slow
def test_experiment_runs_every_stage_and_prints_one_line(tmp_path, capsys):
    # The tiny mode's code path at smaller sizes (make paper-scale-tiny runs the real tiny sizes).
    from studies.experiment import main as experiment

    def run_cli(args, capsys):  # `python -m studies.experiment ARGS` in-process
        experiment([str(a) for a in args])
        return capsys.readouterr().out

    out = tmp_path / "exp"
    line = run_cli(["--tiny", "--offline", "--out", out, "--frames", 3, "--val-frames", 1,
                    "--test-frames", 2, "--samples", 12, "--steps", 2, "--batch", 4, "--jobs", 1, "--quiet"],
                   capsys).strip()
    assert line.count("\n") == 0 and line.startswith("paper-scale: test MAE ")
    for stage in ("synth", "build", "fit", "evaluate", "total"):
        assert f"{stage} " in line
    build = json.loads((out / "shards" / "build.json").read_text())
    assert build["size"] == [348, 128] and build["counts"]["splits"] == {"test": 8, "train": 12, "val": 4}
    result = json.loads((out / "eval.json").read_text())
    assert result["n"] == 8 and f"on {result['n']} images" in line and f"{result['mae']:.3f} %" in line
    train_frames = {r.name for r in (out / "raw" / "train").iterdir()}
    test_frames = {r.name for r in (out / "raw" / "test").iterdir()}
    assert (out / "raw" / "train" / "frame_000000.png").read_bytes() != \
        (out / "raw" / "test" / "frame_000000.png").read_bytes()  # other seeds: other scenes
    assert len(train_frames) == 3 and len(test_frames) == 2
    with pytest.raises(SystemExit):  # a second run refuses to replace the first without --overwrite
        run_cli(["--tiny", "--out", out, "--steps", 1], capsys)
    assert "--overwrite" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # 278x102 cannot pass 7 max-pools: refused before any frame is drawn
        run_cli(["--tiny", "--scale", 0.2, "--out", tmp_path / "small"], capsys)
    assert "too small" in capsys.readouterr().err and not (tmp_path / "small").exists()


# --- --target bend ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def bend_run(shards, tmp_path_factory) -> Path:
    """A short fit on the synthetic shards' bend_pct (half of their APPD, see synthetic_shards)."""
    run = tmp_path_factory.mktemp("runs") / "bend"
    main(["fit", "--shards", str(shards), "--run", str(run), "--steps", "4", "--batch", "8", "--ckpt-every", "4",
          "--workers", "0", "--val-fraction", "0.2", "--target", "bend", "--quiet"])
    return run


def test_fit_on_bend_learns_the_bend_column_and_evaluate_scores_it(bend_run, shards, tmp_path, capsys):
    import pyarrow.parquet as pq

    from train import checkpoint

    state = checkpoint.load(bend_run / "last.pt")
    assert checkpoint.target(state) == "bend" and state["config"]["label"] == "bend_pct"
    rows = pq.read_table(shards / "labels.parquet").to_pylist()
    sel = state["config"]["data"]
    train_bend = [r["bend_pct"] for r in rows if r["split"] == "train"]
    assert sel["n_train"] < len(train_bend)  # a holdout took some of the train split …
    assert 0.3 * np.mean(train_bend) < checkpoint.label_mean(state) < 0.7 * np.mean(
        [r["appd_pct"] for r in rows if r["split"] == "train"])  # … and the mean is the bend's, not the APPD's
    capsys.readouterr()
    main(["evaluate", "--ckpt", str(bend_run / "last.pt"), "--shards", str(shards), "--workers", "0"])
    out = capsys.readouterr()
    result = json.loads(out.out)
    test_bend = np.array([r["bend_pct"] for r in rows if r["split"] == "test"])
    assert result["target"] == "bend" and result["label"] == "bend_pct" and "(bend_pct)" in out.err
    assert result["mean_predictor_mae"] == pytest.approx(np.abs(checkpoint.label_mean(state) - test_bend).mean())


def test_resume_refuses_another_target(bend_run, shards, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["fit", "--shards", str(shards), "--run", str(bend_run), "--steps", "6", "--batch", "8", "--workers",
              "0", "--resume", "--quiet"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "trained on --target bend" in err and err.count("\n") == 1, err


def test_resume_refuses_the_other_kind_of_run_and_another_size(tmp_path):
    from types import SimpleNamespace

    from train import checkpoint
    from train.loop import resumed

    state = checkpoint.initial(ModelConfig(128, 128), 0, {"target": "appd", "data": {"online": True}})
    checkpoint.save(tmp_path / "last.pt", state)
    shards = SimpleNamespace(resume=True, target="appd", online=None)
    with pytest.raises(TrainError, match="a --online run; resume it with --online"):
        resumed(tmp_path, shards, (128, 128))
    online = SimpleNamespace(resume=True, target="appd", online=object())
    with pytest.raises(TrainError, match="trained on 128x128 images, not 256x128"):
        resumed(tmp_path, online, (256, 128))
    assert resumed(tmp_path, online, (128, 128))["config"]["data"] == {"online": True}


def test_bend_on_a_build_from_before_the_bend_columns_is_one_line(shards, tmp_path, capsys):
    import pyarrow.parquet as pq

    old = tmp_path / "old"
    shutil.copytree(shards, old)
    table = pq.read_table(old / "labels.parquet")
    pq.write_table(table.drop_columns(["bend_px", "bend_pct", "shift_x_px", "shift_y_px", "scale"]),
                   old / "labels.parquet")
    with pytest.raises(SystemExit) as exc:
        main(["fit", "--shards", str(old), "--run", str(tmp_path / "run"), "--steps", "1", "--target", "bend",
              "--workers", "0", "--quiet"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and str(old) in err and "bend_pct" in err and err.count("\n") == 1, err
    assert not (tmp_path / "run").exists()


def test_predict_says_what_the_network_was_trained_on(bend_run, shards, capsys):
    import tarfile

    folder = bend_run.parent / "imgs"  # two of the shards' images as files
    folder.mkdir(exist_ok=True)
    with tarfile.open(sorted(shards.glob("shard-*.tar"))[0]) as tar:
        pngs = [m for m in tar.getmembers() if m.name.endswith(".png")][:2]
        for m in pngs:
            (folder / m.name).write_bytes(tar.extractfile(m).read())
    capsys.readouterr()
    main(["predict", "--ckpt", str(bend_run / "last.pt"), str(folder), "--json", "--device", "cpu"])
    assert json.loads(capsys.readouterr().out)["summary"]["target"] == "bend"
    main(["predict", "--ckpt", str(bend_run / "last.pt"), str(folder), "--device", "cpu"])
    assert "running median of bend_pct" in capsys.readouterr().out


def test_the_detection_threshold_has_one_owner() -> None:
    from appdgen.detect import DEFAULT_THRESHOLD_PCT
    from train import evaluate, predict, scoring
    from train.cli import cli

    assert scoring.THRESHOLD is DEFAULT_THRESHOLD_PCT
    for command in ("evaluate", "predict"):
        options = {o.name: o for o in cli.commands[command].params}
        assert options["threshold"].default is DEFAULT_THRESHOLD_PCT, command
    functions = (evaluate.evaluate, evaluate.evaluate_frames, predict.predict_stream)
    assert all(DEFAULT_THRESHOLD_PCT in f.__defaults__ for f in functions)
