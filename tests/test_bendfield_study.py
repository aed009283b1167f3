"""The bend-field study's harness (studies/bendfield.py): its metrics against hand computations, and a tiny run
whose stored readings give its table's numbers and whose labels are APPD(reference, belief)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from studies import bendfield
from studies.bendfield import BendOptions, arm_metrics, frames_to_flag, stream_metrics


def frame(appd, bend=None):
    """A stored reading (None: abstained)."""
    return {"appd": appd, "bend": bend, "p_above": None, "verdict": "ok", "segments": 10}


def test_metrics_by_hand():
    """Per frame, an abstention predicts the mean; the pooled reading is scored per sequence."""
    seqs = [{"appd": 0.2, "bend": 0.1, "frames": [frame(0.3, 0.1), frame(None)], "pooled": frame(0.25, 0.1)},
            {"appd": 0.8, "bend": 0.3, "frames": [frame(0.6, 0.2), frame(0.9, 0.4)], "pooled": frame(None)}]
    m = arm_metrics(seqs, "appd", 0.5, 2)
    per_frame_mae = (0.1 + 0.3 + 0.2 + 0.1) / 4
    assert m["ratio"] == pytest.approx(per_frame_mae / 0.3)
    assert m["pooled"] == pytest.approx((0.05 + 0.3) / 2 / 0.3)
    assert m["seq_mean"] == pytest.approx((abs(0.4 - 0.2) + abs(0.75 - 0.8)) / 2 / 0.3)
    assert (m["abstained"], m["pooled_abstained"], m["sequences"]) == (1, 1, 2)
    assert m["auc"] == pytest.approx(1.0) and m["pooled_auc"] == pytest.approx(1.0)


def test_sequential_test_by_hand():
    """Frames to the first "miscalibrated" verdict; flagged full windows per 1,000 and flagged disjoint sequences."""
    said = lambda *verdicts: [{**frame(0.3), "verdict": v} for v in verdicts]  # noqa: E731
    assert frames_to_flag(said("ok", "uncertain", "miscalibrated", "ok")) == 3
    assert frames_to_flag(said("ok", "ok")) is None
    truth = said("ok", "miscalibrated", "ok", "ok", "miscalibrated", "ok")  # windows of 2 from frame 2 on: 5
    o = BendOptions(window=2, length=2, horizon=4)
    frames = [frame(0.1), frame(None), frame(0.3)]
    s = stream_metrics({"streams": [{"frames_to_flag": 2}, {"frames_to_flag": None}], "truth": truth,
                        "truth_frames": frames}, o)
    assert (s["flagged"], s["miscalibrated"], s["median_frames"]) == (1, 2, 2.0)
    assert s["false_alarms_per_1000"] == pytest.approx(1000 * 2 / 5)
    assert (s["sequences"], s["sequences_flagged"]) == (3, 1)
    assert s["truth_frame_appd"] == pytest.approx(0.2) and s["truth_window_appd"] == pytest.approx(0.3)


def test_tiny_run(tmp_path):
    """Two sequences of three unseen streets at 348x128: the table's numbers come from the stored readings and the
    labels are APPD and bend of (reference, belief) as appdgen computes them."""
    from appdgen.geometry.appd import appd

    o = BendOptions(**{**bendfield.TINY, "out": str(tmp_path), "axes": ("unseen",), "lenses": ()})
    summary = bendfield.run(o, log=lambda line: None)
    assert {(r["axis"], r["target"]) for r in summary["rows"]} == {("unseen", "appd"), ("unseen", "bend")}
    stored = json.loads((tmp_path / "readings.json").read_text())
    seqs = stored["readings"]["unseen"]["sequences"][""]
    assert len(seqs) == 2 and all(len(s["frames"]) == 3 for s in seqs)
    mean = stored["means"]["unseen"]["appd"]
    pooled = [mean if s["pooled"]["appd"] is None else s["pooled"]["appd"] for s in seqs]
    truth = np.array([s["appd"] for s in seqs])
    row = next(r for r in summary["rows"] if r["target"] == "appd")
    assert row["pooled"] == pytest.approx(np.abs(np.array(pooled) - truth).mean() / np.abs(mean - truth).mean())
    scene = bendfield.street_scenes(o)[0]
    draw = scene.recipe.sampler().draw(scene.seed, 0)
    assert seqs[0]["appd"] == pytest.approx(appd(scene.recipe.reference, draw.calib)[1], abs=1e-4)
    assert len(stored["readings"]["unseen"]["truth"]) == 6  # the true calibration read at every unseen frame
