"""A mono camera's bag end to end (issue 20): a 1-channel build, a 1-channel network, predict on the bag itself."""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("rosbags")  # appdgen[ros]
pytest.importorskip("av")  # appdgen[video]

from appdgen.synth.recording import FRAME_PERIOD_NS, START_NS, write_bag, write_video  # noqa: E402
from helpers import kitti_text, raw_image, run_cli, scaled  # noqa: E402
from train.cli import main  # noqa: E402

FRAMES = 4


@pytest.fixture(scope="module")
def mono_run(tmp_path_factory: pytest.TempPathFactory, kitti_quarter) -> Path:
    """A mono bag at 348x128, its grey build and a two-step fit on it."""
    root = tmp_path_factory.mktemp("mono")
    (root / "calib.txt").write_text(kitti_text({"02": kitti_quarter}))
    frames = [raw_image(kitti_quarter.size, i) for i in range(FRAMES)]
    write_bag(root / "mono.bag", [cv2.cvtColor(f, cv2.COLOR_BGR2GRAY) for f in frames])
    write_video(root / "colour.mp4", frames)
    result = run_cli(["build", "--calib", str(root / "calib.txt"), "--images", str(root / "mono.bag"), "--out",
                      str(root / "shards"), "--samples", "8", "--jobs", "1", "--quiet"])
    assert result.exit_code == 0, result.output
    main(["fit", "--shards", str(root / "shards"), "--run", str(root / "run"), "--steps", "2", "--batch", "4",
          "--workers", "0", "--split", "all", "--val-split", "none", "--stats-samples", "8", "--quiet"])
    return root


@pytest.fixture(scope="module")
def kitti_quarter():
    """KITTI camera 02 at 1/4 size (348x128: the smallest the paper's network takes)."""
    from conftest import KITTI_2011_09_26

    return scaled(KITTI_2011_09_26["02"], 4)


def test_a_mono_build_trains_a_one_channel_network(mono_run: Path) -> None:
    assert json.loads((mono_run / "shards" / "build.json").read_text())["channels"] == 1
    ckpt = torch.load(mono_run / "run" / "last.pt", weights_only=True)
    assert ckpt["config"]["model"]["channels"] == "grey"
    assert ckpt["model"]["features.0.0.weight"].shape[1] == 1  # the first conv takes one channel


def test_predict_streams_a_bags_frames_with_timestamps(mono_run: Path, capsys) -> None:
    args = ["predict", "--ckpt", str(mono_run / "run" / "last.pt"), "--calib", str(mono_run / "calib.txt"),
            "--camera", "02"]
    main([*args, str(mono_run / "mono.bag")])
    lines = capsys.readouterr().out.splitlines()
    stamps = [int(line.split("\t")[0]) for line in lines[:-1]]
    assert stamps == [START_NS + i * FRAME_PERIOD_NS for i in range(FRAMES)]
    assert lines[-1].startswith(f"# {FRAMES} images, running median")
    main([*args, "--every", "2", str(mono_run / "colour.mp4")])  # a colour video, taken as grey by this network
    lines = capsys.readouterr().out.splitlines()
    assert [line.split("\t")[1] for line in lines[:-1]] == [f"{mono_run / 'colour.mp4'}/000000",
                                                             f"{mono_run / 'colour.mp4'}/000002"]


def test_predict_refuses_a_bag_of_another_size(mono_run: Path, tmp_path: Path, capsys) -> None:
    bag = tmp_path / "small.bag"
    write_bag(bag, [raw_image((100, 60), 0)])
    with pytest.raises(SystemExit) as exc:
        main(["predict", "--ckpt", str(mono_run / "run" / "last.pt"), "--calib", str(mono_run / "calib.txt"),
              str(bag)])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and str(bag) in err and "/cam0/image_raw" in err and "348x128" in err


def test_export_takes_one_channel(mono_run: Path, tmp_path: Path, capsys) -> None:
    main(["export", "--ckpt", str(mono_run / "run" / "last.pt"), "--pt2", str(tmp_path / "m.pt2")])
    program = torch.export.load(str(tmp_path / "m.pt2")).module()
    assert program(torch.rand(2, 1, 128, 348)).shape == (2,)


def test_fit_online_trains_on_a_bags_frames(mono_run: Path, kitti_quarter, tmp_path: Path, capsys) -> None:
    from appdgen.sources.inputs import resolve_inputs
    from appdgen.sources.recordings import FrameChoice
    from train.online.recipe import decode_frames

    calib, bag = str(mono_run / "calib.txt"), str(mono_run / "mono.bag")
    inputs = resolve_inputs(bag, calib, "02")
    grey = [cv2.cvtColor(raw_image(kitti_quarter.size, i), cv2.COLOR_BGR2GRAY) for i in range(FRAMES)]
    held = decode_frames(list(inputs.images))  # the bag's frames, in order, grey ones as BGR (online is colour)
    assert np.array_equal(held, np.stack([cv2.cvtColor(g, cv2.COLOR_GRAY2BGR) for g in grey]))
    main(["fit", "--online", "--calib", calib, "--camera", "02", "--images", bag, "--every", "2", "--run",
          str(tmp_path / "run"), "--steps", "1", "--batch", "2", "--workers", "0", "--val-split", "none", "--quiet"])
    assert json.loads(capsys.readouterr().out.splitlines()[-1])["step"] == 1
    ckpt = torch.load(tmp_path / "run" / "last.pt", weights_only=True)
    assert ckpt["config"]["fit"]["online"]["every"] == 2  # the frame choice is part of the run's data, kept on resume
    assert len(resolve_inputs(bag, calib, "02", choice=FrameChoice(every=2)).images) == FRAMES // 2
