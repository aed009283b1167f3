"""studies.edgebias: its exact step image and its spread estimator, against values known by construction."""
from __future__ import annotations

import numpy as np
import pytest

from studies.edgebias import spread, step_image


def test_the_step_image_holds_the_line_where_it_was_drawn() -> None:
    img = step_image(0.0, 80.25, 0.0, size=(40, 160), supersample=8).astype(float)
    column = (img[:, 0] - 60) / 120  # coverage of each pixel row [i, i+1) by the bright side y < 80.25
    assert column[:80].min() == 1 and column[81:].max() == 0
    assert column[80] == pytest.approx(0.25, abs=1 / 240)  # one grey level of rounding
    for supersample in (8, 32):  # the coverage is exact to half a sub-row, and a grey level's rounding
        tilted = step_image(0.05, 80.0, 0.0, size=(200, 160), supersample=supersample)
        rows = ((tilted.astype(float) - 60) / 120).sum(0)  # bright rows per column = the line's height there
        np.testing.assert_allclose(rows, 80.0 + 0.05 * (np.arange(200) + 0.5), atol=0.5 / supersample + 1 / 240)


def test_spread_recovers_the_curvature_sd_beyond_noise() -> None:
    rng = np.random.default_rng(0)
    noise = rng.uniform(0.01, 0.09, 20_000)  # each segment's noise variance
    k = rng.normal(0.0, np.sqrt(0.2 ** 2 + noise))
    assert spread(k, noise) == pytest.approx(0.2, rel=0.05)
    assert spread(rng.normal(0.0, np.sqrt(noise)), noise) < 0.05  # noise alone: (almost) no spread
