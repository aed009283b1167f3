"""studies.realsets: its scores of a hand-made set of readings, counted by hand."""
from __future__ import annotations

import pytest

from studies.realsets import frames_to_flag, pool_sizes, scores, single_stride


def row(truth: float, appd: float | None, sd: float | None, verdict: str, baseline: bool = True) -> dict:
    """One window's reading as read_set records it."""
    return {"belief": 0, "truth": truth, "baseline": baseline, "first": 0, "appd": appd, "sd": sd,
            "verdict": verdict, "reason": None}


def test_scores_count_coverage_flags_and_the_mean_predictor_by_hand() -> None:
    rows = [row(0.0, 0.1, 0.1, "ok"), row(0.0, 0.6, 0.1, "miscalibrated"),  # a false alarm, outside 2 sd
            row(0.8, 0.5, 0.2, "uncertain"), row(0.8, 0.9, 0.03, "miscalibrated"),  # the last outside 2 sd
            row(0.3, None, None, "abstain"),  # abstentions are not scored
            row(0.8, 3.0, 0.1, "miscalibrated", baseline=False)]  # the other variant
    s = scores({"set": "toy", "mean": 0.4, "rows": rows}, with_baseline=True)
    assert s["windows"] == 4 and s["true_flagged"] == "1/2" and s["above_flagged"] == "1/2"
    assert s["coverage"] == pytest.approx(2 / 4)
    errors, mean_errors = [0.1, 0.6, 0.3, 0.1], [0.4, 0.4, 0.4, 0.4]
    assert s["mae_vs_mean"] == pytest.approx(sum(errors) / sum(mean_errors))
    assert s["median_sd"] == pytest.approx(0.1) and s["true_reads"] == [0.1, 0.6]


def test_sd_below_spread_counts_windows_narrower_than_their_beliefs_scatter() -> None:
    rows = [row(0.5, 0.2, 0.1, "uncertain"), row(0.5, 0.4, 0.3, "uncertain"),  # reads' sd 0.1414: one below
            dict(row(0.7, 0.7, 0.01, "miscalibrated"), belief=1)]  # a single window has no scatter: not counted
    s = scores({"set": "toy", "mean": 0.4, "rows": rows}, with_baseline=True)
    assert s["sd_below_spread"] == "1/2"
    assert s["sd_over_spread"] == pytest.approx((0.1 + 0.3) / 2 / 0.2 * 2 ** 0.5)


def test_pool_sizes_double_from_the_window_to_every_frame() -> None:
    assert pool_sizes(50, 200) == [50, 100, 200]
    assert pool_sizes(10, 60) == [10, 20, 40, 60]
    assert pool_sizes(10, 10) == [10] and pool_sizes(10, 7) == [7]


def test_frames_to_flag_is_the_least_pool_flagged_per_belief() -> None:
    def grown(truth: float, frames: int, verdict: str, baseline: bool = True, appd: float | None = 0.5,
              belief: int = 1) -> dict:
        return {"belief": belief, "truth": truth, "baseline": baseline, "frames": frames, "appd": appd, "sd": 0.1,
                "verdict": verdict}

    rows = [grown(0.98, 10, "uncertain"), grown(0.98, 20, "miscalibrated"), grown(0.98, 40, "uncertain"),
            grown(0.98, 40, "miscalibrated", baseline=False),  # the other variant
            grown(0.981, 10, "uncertain", belief=2),  # another belief of the same rounded APPD stays apart
            grown(0.0, 10, "abstain", appd=None, belief=0), grown(0.0, 20, "ok", belief=0)]
    out = frames_to_flag({"grown": rows}, with_baseline=True)
    assert out["belief 1 (0.98 %)"]["flagged_at"] == 20 and len(out["belief 1 (0.98 %)"]["reads"]) == 3
    assert out["belief 2 (0.98 %)"] == {"flagged_at": None, "reads": ["10: 0.50±0.10"]}
    assert out["belief 0 (0.00 %)"] == {"flagged_at": None, "reads": ["10: abstain", "20: 0.50±0.10"]}
    assert frames_to_flag({"grown": rows}, with_baseline=False)["belief 1 (0.98 %)"]["flagged_at"] == 40


def test_single_frames_are_about_ten_per_window() -> None:
    assert single_stride(50) == 5 and single_stride(10) == 1 and single_stride(3) == 1
    assert len(range(0, 200, single_stride(50))) == 40 and len(range(0, 60, single_stride(10))) == 60
