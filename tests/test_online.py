"""fit --online: fresh (frame, calibration) pairs drawn as training goes, rendered as build renders them."""
from __future__ import annotations

import csv
import json
import tarfile
from pathlib import Path

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest

torch = pytest.importorskip("torch")

from appdgen.calib.calibration import Calibration  # noqa: E402
from appdgen.geometry.crop import Crop  # noqa: E402
from appdgen.geometry.maps import rectify  # noqa: E402
from appdgen.sources.frames import RawImage  # noqa: E402
from helpers import Setup, kitti_text, raw_image, write_png  # noqa: E402
from train import checkpoint  # noqa: E402
from train.cli import main  # noqa: E402
from train.holdout import frame_sides  # noqa: E402
from train.online.options import OnlineOptions  # noqa: E402
from train.online.pairs import PairSpec, pair_loader  # noqa: E402
from train.online.recipe import decode_frames, open_recipe  # noqa: E402

NET = "348x128"  # the smallest KITTI-aspect size the paper's CNN takes (7 max-pools: 128 px)
DRIVES = ("2011_09_26_drive_0001", "2011_09_26_drive_0002", "2011_09_26_drive_0005")


@pytest.fixture(scope="module")
def frames(tmp_path_factory, small_camera: Calibration) -> tuple[Path, Path]:
    """(calibration file, image folder): the 174x64 KITTI camera and two raw frames in each of three drives."""
    root = tmp_path_factory.mktemp("online")
    calib = root / "calib_cam_to_cam.txt"
    calib.write_text(kitti_text({"02": small_camera}))
    for d, drive in enumerate(DRIVES):
        for i in range(2):
            write_png(root / "images" / drive / f"{i:010d}.png", raw_image(small_camera.size, 10 * d + i))
    return calib, root / "images"


def fit_args(frames, run: Path, *extra) -> list[str]:
    """`python -m train fit --online` on the fixture: tiny batches, few images for stats and validation."""
    calib, images = frames
    return ["fit", "--online", "--calib", str(calib), "--images", str(images), "--size", NET, "--run", str(run),
            "--batch", "2", "--workers", "0", "--stats-samples", "4", "--val-max", "4", "--log-every", "1",
            "--device", "cpu", "--precision", "fp32", "--quiet", *map(str, extra)]


def losses(run: Path) -> list[tuple[int, float]]:
    """(step, train_loss) rows of a run's log.csv."""
    with open(run / "log.csv") as fh:
        return [(int(r["step"]), float(r["train_loss"])) for r in csv.DictReader(fh)]


def run_fit(args: list[str], capsys) -> dict:
    """fit's JSON summary."""
    main(args)
    return json.loads(capsys.readouterr().out)


@pytest.fixture(scope="module")
def online_run(frames, tmp_path_factory) -> Path:
    """Four steps of an online fit with the cpu renderer (validation on held-out drives)."""
    run = tmp_path_factory.mktemp("runs") / "cpu"
    main(fit_args(frames, run, "--steps", 4, "--ckpt-every", 2, "--render", "cpu"))
    return run


def test_online_fit_records_how_it_rectified(online_run):
    state = checkpoint.load(online_run / "last.pt")
    assert state["step"] == 4 and len(losses(online_run)) == 4
    rule = checkpoint.rectify_rule(state)
    assert rule == {"max_fov": None, "interp": "lanczos4", "size": [348, 128], "crop": "valid_region",
                    "render": "cpu"}
    assert state["config"]["data"]["online"] and state["config"]["data"]["n_train"] == 4  # one drive held out
    assert (online_run / "best.pt").exists()


def test_the_same_seed_gives_the_same_losses_and_resume_continues_exactly(frames, online_run, tmp_path, capsys):
    run = tmp_path / "again"
    main(fit_args(frames, run, "--steps", 2, "--ckpt-every", 2, "--render", "cpu"))
    assert losses(run) == losses(online_run)[:2]  # same seed, same images, same weights
    main(fit_args(frames, run, "--steps", 4, "--ckpt-every", 2, "--render", "cpu", "--resume"))
    assert losses(run) == losses(online_run)  # interrupted at step 2: the same losses as uninterrupted
    other = tmp_path / "seed"
    main(fit_args(frames, other, "--steps", 1, "--render", "cpu", "--seed", 1))
    assert losses(other)[0] != losses(online_run)[0]


@pytest.mark.slow
def test_device_renderer_runs_on_cpu_torch(frames, tmp_path, capsys):
    summary = run_fit(fit_args(frames, tmp_path / "dev", "--steps", 2, "--render", "device", "--interp", "cubic"),
                      capsys)
    assert summary["render"] == "device" and summary["step"] == 2 and np.isfinite(summary["val_mae"])
    with pytest.raises(SystemExit) as exc:  # grid_sample has no Lanczos kernel: refused in one line
        main(fit_args(frames, tmp_path / "lanczos", "--steps", 1, "--render", "device"))
    assert exc.value.code == 2 and "lanczos4" in capsys.readouterr().err


def test_batches_do_not_depend_on_workers_and_device_images_match_cpu(frames):
    scene, images = open_recipe(OnlineOptions(str(frames[0]), str(frames[1]), size=NET, interp="cubic"))
    raw = decode_frames(images)
    cpu = PairSpec(scene, raw, seed=3, batch=2, render="cpu", count=6)
    alone = list(pair_loader(cpu, 0))
    two = list(pair_loader(cpu, 2))
    assert len(alone) == 3 and all(torch.equal(a["image"], b["image"]) and torch.equal(a["label"], b["label"])
                                   for a, b in zip(alone, two, strict=True))
    from train.online.render import DeviceFrames

    device = list(pair_loader(PairSpec(scene, raw, 3, 2, "device", count=6), 0))
    rendered = DeviceFrames(raw, scene, torch.device("cpu")).render(device[0])
    diff = (rendered.int() - alone[0]["image"].int()).abs()
    # grid_sample bicubic (A = -0.75) against cv2 INTER_CUBIC with 1/32 px positions: a few levels at most
    assert torch.equal(device[0]["label"], alone[0]["label"]) and diff.float().mean() < 1.0 and diff.max() <= 16


def test_a_cpu_sample_is_the_builds_sample_byte_for_byte(reference_build: Path, setup: Setup):
    build = json.loads((reference_build / "build.json").read_text())
    opts = OnlineOptions(str(setup.calib), str(setup.images), size=setup.size, interp=build["interp"])
    scene, images = open_recipe(opts)
    raw = decode_frames(images)
    rows = pq.read_table(reference_build / "labels.parquet").to_pylist()
    sampler = scene.sampler()
    names = [i.name for i in images]
    with tarfile.open(reference_build / rows[0]["shard"]) as tar:
        for row in rows[:8]:
            data = tar.extractfile(f"{row['key']}.png").read()
            built = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
            draw = sampler.draw(setup.seed, row["sample_index"])
            image = scene.render(raw[names.index(row["raw_path"])], draw)
            assert image.tobytes() == built.tobytes()
            assert draw.appd_px == row["appd_px"]


def test_a_builds_labels_are_a_bank_of_calibrations_and_crops(reference_build: Path, small_camera: Calibration):
    row = pq.read_table(reference_build / "labels.parquet").to_pylist()[5]
    calib = Calibration(*small_camera.size, *(row[n] for n in small_camera.param_names))
    crop = Crop(row["crop_x0"], row["crop_y0"], row["crop_x1"], row["crop_y1"])
    rect = rectify(calib, (row["width"], row["height"]), crop)  # no search: the stored crop as it is
    assert rect.new_camera_matrix[[0, 1, 0, 1], [0, 1, 2, 2]].tolist() == [row[k] for k in
                                                                            ("new_fx", "new_fy", "new_cx", "new_cy")]


def test_predict_calib_takes_an_online_checkpoint(online_run, frames, capsys):
    calib, images = frames
    raw = sorted(images.rglob("*.png"))[:3]
    main(["predict", "--ckpt", str(online_run / "last.pt"), "--calib", str(calib), "--camera", "02",
          *map(str, raw), "--json", "--device", "cpu"])
    preds = json.loads(capsys.readouterr().out)["predictions"]
    assert len(preds) == 3 and all(np.isfinite(p["appd_pct"]) for p in preds)


def test_holdout_keeps_recordings_whole():
    images = [RawImage(Path(f"{d}/{i}.png"), f"{d}/{i}.png", "all") for d in DRIVES for i in range(3)]
    train, val = frame_sides(images, "train", "auto", 0.3, "recording")
    drives = lambda side: {i.name.split("/")[0] for i in side}  # noqa: E731
    assert len(drives(val)) == 1 and not drives(val) & drives(train) and len(train) + len(val) == 9
    split = [RawImage(i.path, i.name, "val" if i.name.startswith(DRIVES[0]) else "train") for i in images]
    train, val = frame_sides(split, "train", "auto", 0.3, "recording")
    assert drives(val) == {DRIVES[0]} and drives(train) == set(DRIVES[1:])


def test_online_options_errors_are_one_line(frames, tmp_path, capsys):
    calib, images = frames
    for args, needle in ((["fit", "--online", "--images", str(images), "--run", str(tmp_path / "a"), "--steps", "1"],
                          "--calib"),
                         (["fit", "--calib", str(calib), "--run", str(tmp_path / "b"), "--steps", "1"], "--online"),
                         (fit_args(frames, tmp_path / "c", "--steps", 1, "--appd-max", 50), "--appd-max")):
        with pytest.raises(SystemExit) as exc:
            main(args)
        err = capsys.readouterr().err
        assert exc.value.code == 2 and needle in err and err.count("\n") == 1, err


@pytest.mark.slow
def test_experiment_goes_online_without_a_training_build(tmp_path, capsys):
    from studies.experiment import main as experiment

    out = tmp_path / "exp"
    experiment(["--tiny", "--out", str(out), "--frames", "3", "--val-frames", "1", "--test-frames", "2",
          "--samples", "12", "--steps", "2", "--batch", "4", "--jobs", "1", "--workers", "0", "--quiet"])
    line = capsys.readouterr().out.strip()
    assert line.startswith("paper-scale: test MAE ") and "fresh pairs of 3 frames, cpu render" in line
    build = json.loads((out / "shards" / "build.json").read_text())
    assert build["counts"]["splits"] == {"test": 8} and build["interp"] == "cubic"  # test frames only
    state = checkpoint.load(out / "run" / "last.pt")
    assert state["config"]["data"]["online"] and checkpoint.rectify_rule(state)["interp"] == "cubic"


def test_builds_from_before_the_crop_columns_still_verify(reference_build: Path, tmp_path: Path):
    import shutil

    from helpers import run_cli as appdgen

    old = tmp_path / "old"
    shutil.copytree(reference_build, old)
    table = pq.read_table(old / "labels.parquet")
    before = ["crop_x0", "crop_y0", "crop_x1", "crop_y1", "bend_px", "bend_pct", "shift_x_px", "shift_y_px", "scale"]
    pq.write_table(table.drop_columns(before), old / "labels.parquet")  # nor the bend, which came after
    assert appdgen(["verify", str(old)]).exit_code == 0
    pq.write_table(table.drop_columns(["crop_x0"]), old / "labels.parquet")  # half the crop: not a known schema
    assert appdgen(["verify", str(old)]).exit_code != 0


@pytest.mark.heavy
def test_online_vs_offline_benchmark_prints_its_table(tmp_path):
    import subprocess
    import sys

    root = Path(__file__).parents[1]
    result = subprocess.run([sys.executable, "-m", "studies.online_vs_offline", "--frames", "6", "--per-frame", "2",
                             "--test-frames", "3",
                             "--minutes", "1", "--batch", "8", "--out", str(tmp_path / "ovo")],
                            capture_output=True, text=True, timeout=600, cwd=root)
    assert result.returncode == 0, result.stderr
    rows = [line for line in result.stdout.splitlines() if line.startswith("| 1 |")]
    assert len(rows) == 1 and rows[0].count("|") == 6


def test_bend_pairs_carry_the_builds_bend_labels(reference_build: Path, setup: Setup):
    build = json.loads((reference_build / "build.json").read_text())
    opts = OnlineOptions(str(setup.calib), str(setup.images), size=setup.size, interp=build["interp"])
    rows = pq.read_table(reference_build / "labels.parquet").to_pylist()[:8]
    for target, column in (("bend", "bend_pct"), ("appd", "appd_pct")):
        scene, images = open_recipe(opts, target)
        batch = PairSpec(scene, decode_frames(images), seed=setup.seed, batch=8, render="cpu", count=8)
        labels = next(iter(pair_loader(batch, 0)))["label"]
        assert labels.tolist() == torch.tensor([r[column] for r in rows], dtype=torch.float32).tolist()
    assert any(r["bend_pct"] < 0.5 * r["appd_pct"] for r in rows)  # the two targets differ


def test_online_fit_on_bend_records_it_and_resume_keeps_it(frames, tmp_path, capsys):
    run = tmp_path / "bend"
    main(fit_args(frames, run, "--steps", 2, "--ckpt-every", 2, "--render", "cpu", "--target", "bend"))
    state = checkpoint.load(run / "last.pt")
    assert checkpoint.target(state) == "bend" and state["config"]["label"] == "bend_pct"
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        main(fit_args(frames, run, "--steps", 3, "--render", "cpu", "--resume"))  # --target appd by default
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "trained on --target bend" in err and err.count("\n") == 1, err


def test_evaluate_frames_scores_sequences_of_unseen_frames_under_one_draw_each(online_run, frames, tmp_path, capsys):
    from train.inference import to_input
    from train.scoring import SEQUENCE_SEED

    calib, images = frames
    main(["evaluate", "--ckpt", str(online_run / "last.pt"), "--frames", str(images), "--length", "2",
          "--sequences", "2", "--device", "cpu", "--json", str(tmp_path / "e.json")])
    result = json.loads(capsys.readouterr().out)
    assert result == json.loads((tmp_path / "e.json").read_text())
    # the same numbers from the recipe's own pieces: frames in file order, sequence k under draw (SEQUENCE_SEED, k)
    state = checkpoint.load(online_run / "last.pt")
    recipe, listed = open_recipe(OnlineOptions(**state["config"]["fit"]["online"]))
    raw, model = decode_frames(listed), checkpoint.build_model(state)
    truth, pred = [], []
    for k in range(2):
        draw = recipe.sampler().draw(SEQUENCE_SEED, k)
        for f in (2 * k, 2 * k + 1):
            image = torch.from_numpy(recipe.render(raw[f], draw).transpose(2, 0, 1).copy())[None]
            with torch.no_grad():
                pred.append(float(model(to_input({"image": image}, torch.device("cpu")))))
            truth.append(recipe.label(draw))
    truth, pred, mean = np.array(truth), np.array(pred), checkpoint.label_mean(state)
    assert result["n"] == 4 and result["sequences"]["count"] == 2
    assert result["mae"] == pytest.approx(np.abs(pred - truth).mean(), rel=1e-4)
    assert result["mean_predictor_mae"] == pytest.approx(np.abs(mean - truth).mean())
    per_seq = np.abs(np.median(pred.reshape(2, 2), 1) - truth[::2]).mean() / np.abs(mean - truth[::2]).mean()
    assert result["sequences"]["median_vs_mean_predictor"] == pytest.approx(per_seq, rel=1e-4)
    for args, needle in (([], "--shards"), (["--frames", str(images), "--shards", str(tmp_path)], "--shards"),
                         (["--frames", str(images), "--length", "7"], "fewer than one sequence")):
        with pytest.raises(SystemExit):
            main(["evaluate", "--ckpt", str(online_run / "last.pt"), "--device", "cpu", *args])
        assert needle in capsys.readouterr().err


def test_evaluate_frames_refuses_an_offline_checkpoint(tmp_path, capsys):
    from synthetic_shards import write_shards

    shards = write_shards(tmp_path / "shards", n=8, size=(128, 128), per_shard=8)
    main(["fit", "--shards", str(shards), "--run", str(tmp_path / "run"), "--steps", "1", "--batch", "4",
          "--workers", "0", "--val-split", "none", "--stats-samples", "4", "--quiet"])
    capsys.readouterr()
    with pytest.raises(SystemExit):
        main(["evaluate", "--ckpt", str(tmp_path / "run" / "last.pt"), "--frames", str(tmp_path), "--device", "cpu"])
    assert "fit --online" in capsys.readouterr().err
