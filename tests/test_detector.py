"""The detector comparison (studies.detector, `python -m studies.detector`): its metrics (train.scoring's), its dense
target, a run of every arm."""
from __future__ import annotations

import itertools
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from appdgen.analysis.studies import spearman  # noqa: E402
from appdgen.calib.defaults import default_calibration  # noqa: E402
from appdgen.geometry.appd import px_to_pct  # noqa: E402
from appdgen.sampling.options import SamplingOptions  # noqa: E402
from appdgen.sampling.sampler import target_px  # noqa: E402
from appdgen.synth import scale_calibration  # noqa: E402
from helpers import raw_image  # noqa: E402
from studies.detector import (  # noqa: E402
    ARMS,
    FIELD_COLUMNS,
    PAIR_LABELS,
    TUNE_SEED,
    Arm,
    DetectorOptions,
    Stream,
    axis_pairs,
    floor_arms,
    real_frames,
    tune_frames,
)
from studies.experiment import main  # noqa: E402
from train.online.recipe import PairRecipe  # noqa: E402
from train.scoring import auc  # noqa: E402
from train.scoring import sequence_metrics as metrics  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def test_spearman_is_pearson_of_the_ranks_and_ties_share_their_rank():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=50), rng.normal(size=50)
    rank = lambda x: np.argsort(np.argsort(x))  # noqa: E731 (no ties here)
    assert spearman(a, b) == pytest.approx(np.corrcoef(rank(a), rank(b))[0, 1])
    assert spearman(a, a**3) == pytest.approx(1.0) and spearman(a, -a) == pytest.approx(-1.0)
    # ties: x = [1, 1, 2] has ranks [0.5, 0.5, 2]; against y = [0, 1, 2] (ranks 0, 1, 2) that is r = √3/2
    assert spearman(np.array([1.0, 1.0, 2.0]), np.array([0.0, 1.0, 2.0])) == pytest.approx(np.sqrt(3) / 2)


def test_auc_is_the_fraction_of_correctly_ordered_pairs():
    rng = np.random.default_rng(1)
    score, positive = rng.normal(size=40).round(1), rng.random(40) < 0.4
    pairs = [(p, n) for p, n in itertools.product(score[positive], score[~positive])]
    brute = np.mean([1.0 if p > n else 0.5 if p == n else 0.0 for p, n in pairs])
    assert auc(score, positive) == pytest.approx(brute)
    assert auc(positive.astype(float), positive) == 1.0 and np.isnan(auc(score, np.zeros(40, bool)))


def test_metrics_score_a_perfect_and_a_mean_predictor():
    rng = np.random.default_rng(2)
    truth = np.repeat(rng.uniform(0, 1, 6), 5)  # 6 sequences of 5 frames, one miscalibration each
    perfect = metrics(truth, truth, truth, 0.5, 5)
    assert perfect["ratio"] == 0 and perfect["seq_mean"] == 0 and perfect["auc"] == 1.0
    noisy = truth + rng.normal(0, 0.2, truth.shape)
    m = metrics(np.full_like(truth, 0.5), truth, truth, 0.5, 5)
    assert m["ratio"] == pytest.approx(1.0) and m["seq_median"] == pytest.approx(1.0) and m["sequences"] == 6
    # averaging a sequence's noisy predictions helps: the sequence ratio is below the per-image one
    n = metrics(noisy, truth, truth, 0.5, 5)
    assert n["seq_mean"] < n["ratio"]


def test_the_dense_targets_read_off_is_appd_and_bend():
    ref = scale_calibration(default_calibration(), 0.25)
    scene = PairRecipe(ref, "02", ref.size, SamplingOptions.parse(ref, None, 1.0, 0.01, None, "cubic"))
    sampler = scene.sampler()
    for i in range(5):
        draw = sampler.draw(3, i)
        appd, bend, dense = (PAIR_LABELS[t](scene, draw) for t in ("appd", "bend", "field"))
        points = dense.reshape(-1, 4)
        assert len(points) == FIELD_COLUMNS * 4  # 12 × 4 at KITTI's aspect
        assert appd == pytest.approx(px_to_pct(draw.appd_px, ref))
        # the coarse grid's mean lengths are the labels to a few per cent (the field is smooth)
        assert np.hypot(points[:, 0], points[:, 1]).mean() == pytest.approx(appd, rel=0.05, abs=1e-4)
        assert np.hypot(points[:, 2], points[:, 3]).mean() == pytest.approx(bend, rel=0.1, abs=1e-4)
        assert bend <= appd * 1.05 + 1e-6


def test_the_synthetic_axes_draw_the_same_miscalibrations_one_per_sequence():
    ref = scale_calibration(default_calibration(), 0.25)
    scene = PairRecipe(ref, "02", ref.size, SamplingOptions.parse(ref, None, 1.0, 0.01, None, "cubic"))
    s = Stream(scene, {name: np.stack([raw_image(ref.size, 10 * n + i) for i in range(6)])
                       for n, name in enumerate(("train", "viewpoint", "unseen"))})
    o = DetectorOptions(sequences=2, length=3)
    pairs = {axis: axis_pairs(s, axis, o) for axis in ("views", "viewpoint", "unseen")}
    for t in ("appd", "bend"):
        # every frame of a sequence under one draw; the axes differ by their scenes only
        labels = pairs["unseen"][t].reshape(2, 3)
        assert (labels == labels[:, :1]).all() and labels[0, 0] != labels[1, 0]
        for axis in ("views", "viewpoint"):
            assert np.array_equal(pairs[axis][t], labels.ravel())
    assert not np.array_equal(pairs["views"]["image"], pairs["unseen"]["image"])


def test_the_finetune_frames_come_first_and_never_reach_the_real_axis(tmp_path):
    names = [f"{1403715273262142976 + 50_000_000 * i}.png" for i in range(25)]  # time stamps, recording order
    for name in reversed(names):
        (tmp_path / name).write_bytes(b"")
    o = DetectorOptions(real=str(tmp_path), length=10, sequences=9, finetune=5)
    assert [p.name for p in tune_frames(o)] == names[:5]
    assert [p.name for p in real_frames(o)] == names[5:]  # two whole sequences of the 20 left
    untuned = DetectorOptions(real=str(tmp_path), length=10, sequences=9)
    assert tune_frames(untuned) == [] and [p.name for p in real_frames(untuned)] == names[:20]


def test_the_finetuned_floor_fits_on_the_synthetic_and_the_real_pairs_and_is_tested_beside_the_sim_only_one():
    ref = scale_calibration(default_calibration(), 0.25)
    scene = PairRecipe(ref, "02", ref.size, SamplingOptions.parse(ref, None, 1.0, 0.01, None, "cubic"))
    s = Stream(scene, {"train": np.stack([raw_image(ref.size, i) for i in range(4)]),
                       "unseen": np.stack([raw_image(ref.size, 50 + i) for i in range(4)]),
                       "tune": np.stack([raw_image(ref.size, 90 + i) for i in range(2)])})
    o = DetectorOptions(sequences=2, length=2, floor_images=6)
    tests = {"unseen": axis_pairs(s, "unseen", o)}
    out = floor_arms([Arm("plumbline", "bend", "full")], s, o, tests)
    assert set(out) == {"plumbline/bend", "plumbline+real2/bend"}
    sampler = scene.sampler()
    bend = lambda seed, i: px_to_pct(target_px(sampler, sampler.draw(seed, i), "bend"), ref)  # noqa: E731
    synthetic, real = [bend(o.seed, i) for i in range(6)], [bend(TUNE_SEED, i) for i in range(6)]
    assert out["plumbline/bend"]["label_mean"] == pytest.approx(np.mean(synthetic))
    assert out["plumbline+real2/bend"]["label_mean"] == pytest.approx(np.mean(synthetic + real))
    assert all(len(a["predictions"]["unseen"]["bend"]) == 4 for a in out.values())


@pytest.mark.slow
def test_every_arm_runs_on_cpu_through_the_experiment(tmp_path, capsys):
    out = tmp_path / "d"
    main(["--detector", "--tiny", "--out", str(out), "--frames", "4", "--samples", "4"])
    printed = capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    found = {(r["arm"], r["target"], r["axis"]) for r in summary["rows"]}
    for arm in (a for a in ARMS if a.model != "plumbline"):
        for axis in ("views", "viewpoint", "unseen"):
            for target in (("appd", "bend") if arm.target == "field" else (arm.target,)):
                assert (arm.name, target, axis) in found and f"| {arm.name} | {target} |" in printed
    assert all(np.isfinite(r["ratio"]) for r in summary["rows"])
    assert summary["streams"]["full"]["size"] == [1392, 512] and summary["streams"]["low"]["size"] == [348, 128]
    assert summary["streams"]["full"]["images"] == 4 and len(list((out / "raw" / "full" / "train").iterdir())) == 4


@pytest.mark.heavy
def test_the_benchmark_tiny_mode_prints_every_arm(tmp_path):
    out = subprocess.run([sys.executable, "-m", "studies.detector", "--tiny", "--out", str(tmp_path / "d")],
                         capture_output=True, text=True, check=True, cwd=ROOT).stdout
    for arm in ARMS:
        if arm.model != "plumbline":
            assert f"| {arm.name} |" in out
    assert '"load_before"' in out
