"""studies.realsets: its scores of a hand-made set of readings, counted by hand."""
from __future__ import annotations

import pytest

from studies.realsets import scores


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
