"""appdgen.analysis.studies and the sweep/reproj/drift commands: laws of each analysis, exact special cases, the CLI."""
from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import KITTI_2011_09_26
from test_geometry import lens_pixels

from appdgen.analysis.studies import (
    PAPER_RANGES,
    drift_matrix,
    physical_error,
    rectify_points,
    reprojection_study,
    round_significant,
    sample_rays,
    spearman,
    study_ranges,
    sweep,
    sweep_fractions,
    synthetic_error,
    to_output,
)
from appdgen.calib.calibration import Calibration
from appdgen.calib.formats import save
from appdgen.cli import main
from appdgen.cli.analyses import file_labels
from appdgen.errors import AppdgenError
from appdgen.geometry.appd import appd_px
from appdgen.geometry.distortion import distort_to_pixels
from appdgen.geometry.maps import rectify

SMALL = (348, 128)  # a quarter of KITTI's raw size per side: fast, and APPD % within 1e-5 of the raw size's
PINHOLE = Calibration(1392, 512, 900.0, 900.0, 696.0, 256.0)  # no distortion


# --- sweep --------------------------------------------------------------------------------------------------------


def test_sweep_is_exactly_zero_at_t0_and_grows_on_both_sides_for_focal_lengths(kitti02):
    t = sweep_fractions(-0.08, 0.08, 17)
    curves = sweep(kitti02, ["fx", "fy"], t, SMALL)
    middle = int(np.flatnonzero(t == 0.0)[0])
    for values in curves.values():
        assert values[middle] == 0.0
        assert (np.diff(values[middle:]) > 0).all() and (np.diff(values[:middle + 1]) < 0).all()


def test_sweep_fractions_snap_zero_and_need_two_steps():
    assert 0.0 in sweep_fractions(-0.2, 0.2, 101)
    with pytest.raises(AppdgenError, match="at least 2"):
        sweep_fractions(-0.2, 0.2, 1)


def test_sweep_skips_zero_parameters_and_gives_nan_for_invalid_calibrations(kitti02):
    calib = kitti02.replace(k2=0.0, k3=0.0, p1=0.0)
    curves = sweep(calib, ["fx", "k1", "p1"], np.array([-1.5, 0.0, 1.0]), SMALL)
    assert list(curves) == ["fx", "k1"]  # p1 = 0: multiplying it changes nothing
    assert np.isnan(curves["fx"][0]) and curves["fx"][2] > 0  # fx × (1 − 1.5) < 0
    assert curves["k1"][0] > 0 and np.isnan(curves["k1"][2])  # k1 doubled, alone: the lens folds over
    with pytest.raises(AppdgenError, match="unknown parameter"):
        sweep(calib, ["fx", "f"], np.array([0.0, 0.1]), SMALL)


# --- reprojection -------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("t", [0.03, -0.03])
def test_synthetic_error_is_appd_on_the_same_points_carried_through_the_map(kitti02, t):
    ref, other = rectify(kitti02, SMALL), rectify(kitti02.perturb(fx=t), SMALL)
    x, y = sample_rays(ref, 400, np.random.default_rng(1))
    ideal = np.array(to_output(ref.new_camera_matrix, x, y))  # p*: where Θ* puts the points in its output
    moved = np.array(rectify_points(other, *distort_to_pixels(x, y, kitti02)))  # pm: the same raw points via Θm
    e = moved - ideal  # the synthetic error vectors (output px)
    assert synthetic_error(ref, other, x, y) == pytest.approx(np.linalg.norm(e, axis=0).mean(), rel=1e-12)

    def maps(rect, pu, pv):  # M̂ in float64 at any output position: raw px (test_geometry checks cv2's maps)
        k = rect.new_camera_matrix
        return np.array(lens_pixels((pu - k[0, 2]) / k[0, 0], (pv - k[1, 2]) / k[1, 1], rect.calib))

    # APPD on the points: d = ‖M̂*(p*) − M̂m(p*)‖ (raw px). Since M̂*(p*) = raw = M̂m(pm) exactly,
    # d = ‖M̂m(pm) − M̂m(p*)‖: the synthetic error vector carried into raw px by M̂m. The midpoint rule gives
    # d = ‖J(c)·e‖ + R, c = (p* + pm)/2, J = ∂M̂m/∂p, and per component |R| ≤ ‖e‖³·B/24, B bounding M̂m's third
    # directional derivative: B ≤ max(fx, fy)·C / min(K̂x, K̂y)³ with C = 6|k1| + 120|k2|r² + 840|k3|r⁴ bounding
    # the radial-tangential model's (tangential terms are quadratic: no third derivative) for r ≤ 0.9, beyond
    # KITTI's crop corners (r ≈ 0.8). Hence |d − ‖J e‖| ≤ √2·B·‖e‖³/24, about 6e-4 px for ‖e‖ ≈ 1.5 px; the
    # central differences for J (h = 1e-3 px) add ≈ h²·B·‖e‖/6 < 1e-8 px.
    d = np.linalg.norm(maps(ref, *ideal) - maps(other, *ideal), axis=0)
    c, h = (ideal + moved) / 2, 1e-3
    jx = (maps(other, c[0] + h, c[1]) - maps(other, c[0] - h, c[1])) / (2 * h)
    jy = (maps(other, c[0], c[1] + h) - maps(other, c[0], c[1] - h)) / (2 * h)
    carried = np.linalg.norm(jx * e[0] + jy * e[1], axis=0)
    calib, k = other.calib, other.new_camera_matrix
    C = 6 * abs(calib.k1) + 120 * abs(calib.k2) * 0.9**2 + 840 * abs(calib.k3) * 0.9**4
    B = max(calib.fx, calib.fy) * C / min(k[0, 0], k[1, 1]) ** 3
    assert np.all(np.abs(d - carried) <= math.sqrt(2) * B * np.linalg.norm(e, axis=0) ** 3 / 24 + 1e-8)
    # And d averaged over the points estimates APPD over the whole grid (400 uniform points: a few % apart).
    assert d.mean() == pytest.approx(appd_px(ref, other), rel=0.05)


def test_without_distortion_a_focal_change_is_absorbed_by_the_crop_but_not_by_the_physical_camera():
    t = 0.1
    ref, other = rectify(PINHOLE, SMALL), rectify(PINHOLE.perturb(fx=t), SMALL)
    x, y = sample_rays(ref, 300, np.random.default_rng(2))
    # K̂ rescales with fx and the crop with 1/fx: the rectified image is the same, so APPD and (a) vanish ...
    assert appd_px(ref, other) < 1e-3
    assert synthetic_error(ref, other, x, y) < 1e-9
    # ... while the drifted camera's points land (1 + t)·x from the centre: (b) = K̂x·|t|·mean |x| over those seen.
    seen = np.abs(PINHOLE.fx * (1 + t) * x + PINHOLE.cx - (PINHOLE.width - 1) / 2) <= (PINHOLE.width - 1) / 2
    expected = ref.new_camera_matrix[0, 0] * t * np.abs(x[seen]).mean()
    assert physical_error(ref, other, x, y) == pytest.approx(expected, rel=1e-9)


def test_errors_vanish_for_the_reference_itself(kitti02):
    ref = rectify(kitti02, SMALL)
    x, y = sample_rays(ref, 300, np.random.default_rng(3))
    assert synthetic_error(ref, ref, x, y) < 1e-9 and physical_error(ref, ref, x, y) < 1e-9


def test_reprojection_study_on_kitti02_is_reproducible_and_tight_in_the_synthetic_scenario(kitti02):
    study = reprojection_study(kitti02, 40, seed=5, size=SMALL, points=200)
    again = reprojection_study(kitti02, 40, ("synthetic",), seed=5, size=SMALL, points=200)
    np.testing.assert_array_equal(study.reproj_px["synthetic"], again.reproj_px["synthetic"])
    assert study.fractions.shape == (40, 9) and study.size == SMALL
    lo, hi = np.array(list(PAPER_RANGES.values())).T
    assert ((study.fractions >= lo) & (study.fractions <= hi)).all()
    assert np.allclose(study.appd_pct, study.appd_px * 100 / kitti02.diagonal)
    rho = {name: spearman(study.appd_pct, error) for name, error in study.reproj_px.items()}
    assert rho["synthetic"] > 0.95 and rho["physical"] < rho["synthetic"]


def test_reprojection_study_rejects_bad_arguments(kitti02):
    for kwargs, fragment in (({"scenarios": ("both",)}, "unknown scenario"), ({"samples": 0}, "samples=0"),
                             ({"points": 0}, "points=0")):
        with pytest.raises(AppdgenError, match=fragment):
            reprojection_study(kitti02, **{"samples": 3, **kwargs})


def test_spearman_against_hand_computed_values():
    assert spearman(np.arange(5), np.array([2, 1, 4, 3, 5])) == pytest.approx(0.8)  # 1 − 6·Σd²/(n(n²−1))
    # Ties share their mean rank: ranks (0, 1.5, 1.5, 3) against (0, 1, 2, 3) correlate at √0.9.
    assert spearman(np.array([1, 2, 2, 3, np.nan]), np.array([1, 2, 3, 4, 7])) == pytest.approx(math.sqrt(0.9))
    assert spearman(np.arange(6), -np.exp(np.arange(6))) == pytest.approx(-1.0)
    assert math.isnan(spearman(np.ones(4), np.arange(4)))


# --- drift --------------------------------------------------------------------------------------------------------


def test_drift_of_a_calibration_against_itself_is_zero_and_the_matrix_is_symmetric():
    calibs = [KITTI_2011_09_26["02"], KITTI_2011_09_26["03"], KITTI_2011_09_26["02"]]
    matrix = drift_matrix(calibs, SMALL)
    assert (np.diag(matrix) == 0).all() and matrix[0, 2] == 0.0
    np.testing.assert_array_equal(matrix, matrix.T)
    assert matrix[0, 1] == appd_px(rectify(calibs[0], SMALL), rectify(calibs[1], SMALL)) > 0


def test_drift_needs_one_raw_size():
    with pytest.raises(AppdgenError, match=r"differ in raw size: a 1392x512, b 1280x512"):
        drift_matrix([PINHOLE, PINHOLE.replace(width=1280)], labels=["a", "b"])


def test_file_labels():
    assert file_labels(["a/2011_09_26/calib.txt", "b/2011_09_28/calib.txt"]) == ["2011_09_26", "2011_09_28"]
    assert file_labels(["x/one.yaml", "x/two.yaml"]) == ["one.yaml", "two.yaml"]
    assert file_labels(["d1/c.txt", "d2/c.txt", "other.json"]) == ["d1", "d2", "other.json"]
    assert file_labels(["p/d/c.txt", "q/d/c.txt"]) == ["p/d/c.txt", "q/d/c.txt"]  # still ambiguous: the paths


def test_round_significant():
    rounded = round_significant(KITTI_2011_09_26["02"], 3)
    assert (rounded.fx, rounded.cx, rounded.p2) == (960.0, 696.0, 0.000568)
    assert round_significant(rounded, 3) == rounded


# --- other lens models --------------------------------------------------------------------------------------------

FISHEYE = Calibration(640, 480, 200.0, 200.0, 319.5, 239.5, -0.01, 0.04, -0.04, 0.008, model="kb4")


def test_study_ranges_are_the_papers_for_radtan_and_the_distortion_range_for_other_coefficients(kitti02):
    assert study_ranges(kitti02) == PAPER_RANGES
    assert study_ranges(FISHEYE) == {**{n: PAPER_RANGES[n] for n in ("fx", "fy", "cx", "cy")},
                                     **{n: (-0.15, 0.15) for n in ("k1", "k2", "k3", "k4")}}


def test_sweep_takes_the_models_parameter_names():
    curves = sweep(FISHEYE, ["k4"], np.array([0.0, 0.1]), (160, 120), max_fov=120)
    assert curves["k4"][0] == 0.0 and curves["k4"][1] > 0
    with pytest.raises(AppdgenError, match=r"unknown parameter\(s\) p1 for lens model kb4; expected some of "
                                           r"fx, fy, cx, cy, k1, k2, k3, k4"):
        sweep(FISHEYE, ["p1"], np.array([0.0, 0.1]), (160, 120), max_fov=120)


def test_reprojection_study_of_a_fisheye_perturbs_its_own_coefficients():
    study = reprojection_study(FISHEYE, 8, seed=3, size=(160, 120), points=100, max_fov=120)
    assert study.params == FISHEYE.param_names and study.fractions.shape == (8, 8)
    assert (np.abs(study.fractions[:, 4:]) <= 0.15).all() and np.ptp(study.fractions[:, 7]) > 0
    assert (study.appd_px > 0).all() and np.isfinite(study.reproj_px["synthetic"]).all()


def test_drift_matrix_with_max_fov_bounds_every_calibration():
    calibs = [FISHEYE, FISHEYE.perturb(k2=0.05)]
    matrix = drift_matrix(calibs, (160, 120), max_fov=100)
    assert matrix[0, 1] == appd_px(rectify(calibs[0], (160, 120), max_fov=100),
                                   rectify(calibs[1], (160, 120), max_fov=100)) > 0


def test_fisheye_sweep_plot(tmp_path):
    pytest.importorskip("matplotlib")
    path = tmp_path / "kb4.json"
    save(FISHEYE, path)
    result = run("sweep", "--calib", path, "--steps", "3", "--size", "160x120", "--max-fov", "120",
                 "--plot", tmp_path / "kb4.png")
    assert result.exit_code == 0, result.output
    assert (tmp_path / "kb4.png").read_bytes()[:4] == b"\x89PNG"


# --- command line -------------------------------------------------------------------------------------------------


@pytest.fixture
def days(tmp_path: Path) -> list[str]:
    """Two 'days' of camera 02 as appdgen JSON files with one name in two folders, like KITTI's layout."""
    paths = []
    for day, calib in (("day1", KITTI_2011_09_26["02"]), ("day2", KITTI_2011_09_26["02"].perturb(fx=0.01, cy=0.02))):
        (tmp_path / day).mkdir()
        save(calib, tmp_path / day / "calib.json")
        paths.append(str(tmp_path / day / "calib.json"))
    return paths


def run(*args: str):
    """Invoke the appdgen CLI in-process."""
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def read_csv(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as stream:
        return list(csv.DictReader(stream))


def test_cli_sweep(days, tmp_path):
    out = tmp_path / "sweep.csv"
    result = run("sweep", "--calib", days[0], "--params", "fx,cy", "--from", "-0.1", "--to", "0.1", "--steps", "5",
                 "--size", "348x128", "--csv", out)
    assert result.exit_code == 0, result.output
    assert "+0.0 %" in result.stdout and "fx" in result.stdout
    rows = read_csv(out)
    assert list(rows[0]) == ["t", "appd_pct_fx", "appd_pct_cy"] and len(rows) == 5
    assert float(rows[2]["t"]) == 0.0 and float(rows[2]["appd_pct_fx"]) == 0.0


def test_cli_sweep_notes_skipped_parameters(tmp_path):
    path = tmp_path / "pinhole.json"
    save(PINHOLE, path)
    result = run("sweep", "--calib", path, "--params", "fx,k1", "--steps", "3", "--size", "348x128")
    assert result.exit_code == 0 and "k1 skipped" in result.stderr


def test_cli_reproj(days, tmp_path):
    out = tmp_path / "reproj.csv"
    result = run("reproj", "--calib", days[0], "--samples", "12", "--points", "100", "--size", "348x128",
                 "--scenario", "synthetic", "--csv", out)
    assert result.exit_code == 0, result.output
    assert "Spearman" in result.stdout and "physical" not in result.stdout
    rows = read_csv(out)
    assert len(rows) == 12 and list(rows[0])[-4:] == ["t_k3", "appd_px", "appd_pct", "reproj_synthetic_px"]


def test_cli_drift(days):
    result = run("drift", days[0], days[1], days[0], "--size", "348x128")
    assert result.exit_code == 0, result.output
    # Two files named alike: labelled by folder; the same file twice: labelled by path.
    assert days[0] in result.stdout and "raw px" in result.stdout and "% of the" in result.stdout
    result = run("drift", *days, "--size", "348x128", "--json")
    table = json.loads(result.stdout)
    assert table["labels"] == ["day1", "day2"] and list(table["cameras"]) == ["0"]
    px = np.array(table["cameras"]["0"]["appd_px"])
    assert px[0, 0] == 0 and px[0, 1] == px[1, 0] > 0


@pytest.mark.parametrize("args, fragment", [
    (["sweep", "--calib", "missing.yaml"], "missing.yaml: no such file"),
    (["sweep", "--calib", "{0}", "--params", "fx,f"], "unknown parameter(s) f"),
    (["sweep", "--calib", "{0}", "--steps", "1"], "at least 2"),
    (["reproj", "--calib", "{0}", "--size", "100x100", "--samples", "2"], "aspect"),
    (["reproj", "--calib", "{0}", "--samples", "0"], "samples=0"),
    (["drift", "{0}", "--camera", "7"], "camera"),
    (["drift", "{0}", "{1}"], "differ in raw size"),
])
def test_cli_bad_input_is_one_line_and_exit_2(days, tmp_path, args, fragment):
    """Errors the user can make: one line on stderr, exit status 2, nothing on stdout."""
    other = tmp_path / "other.json"
    save(PINHOLE.replace(width=1280), other)
    size = [] if "--size" in args else ["--size", "348x128"]
    result = run(*(a.format(days[0], other) for a in args), *size)
    assert result.exit_code == 2, result.output
    assert result.stdout == "" and result.stderr.count("\n") == 1
    assert result.stderr.startswith("appdgen: error:") and fragment in result.stderr


def test_cli_unwritable_output_is_one_line_and_exit_2(days, tmp_path):
    # The results are printed first, so a failed --csv does not lose them.
    result = run("sweep", "--calib", days[0], "--steps", "2", "--size", "348x128", "--csv", f"{days[1]}/x.csv")
    assert result.exit_code == 2 and "+20.0 %" in result.stdout
    assert result.stderr.startswith(f"appdgen: error: {days[1]}/x.csv: cannot write: ")
    assert result.stderr.count("\n") == 1


def test_plot_without_matplotlib_is_a_clear_error(days, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib now raises ImportError
    result = run("drift", *days, "--plot", "x.png")
    assert result.exit_code == 2 and "needs matplotlib" in result.stderr and "pip install" in result.stderr


@pytest.mark.parametrize("command", [
    ["sweep", "--calib", "{0}", "--params", "fx,k1", "--steps", "5"],
    ["reproj", "--calib", "{0}", "--samples", "10", "--points", "100"],
    ["drift", "{0}", "{1}"],
])
def test_plots_are_written_as_png(days, tmp_path, command):
    pytest.importorskip("matplotlib")
    out = tmp_path / "figure.png"
    result = run(*(a.format(*days) for a in command), "--size", "348x128", "--plot", out)
    assert result.exit_code == 0, result.output
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size < 200_000


# --- real KITTI files (../shared/data) ----------------------------------------------------------------------------


def test_kitti_days_drift(shared):
    files = sorted(str(p) for p in (shared / "kitti").glob("*/calib_cam_to_cam.txt"))
    result = run("drift", *files, "--size", "348x128", "--json")
    assert result.exit_code == 0, result.output
    table = json.loads(result.stdout)
    assert table["labels"][0] == "2011_09_26" and list(table["cameras"]) == ["02", "03"]
    cam02, cam03 = (np.array(table["cameras"][c]["appd_pct"]) for c in ("02", "03"))
    # Real day-to-day drift: a few pixels, up to about 0.2 % of the diagonal for camera 02, more for camera 03.
    assert (cam02[0, 1:] > 0.02).all() and (cam02[0, 1:] < 0.25).all()
    assert cam03[0, 1:].max() > cam02[0, 1:].max()
    notes = run("drift", *files, "--size", "348x128").stderr
    assert "2011_09_29, 2011_09_30, 2011_10_03: values have at most 3 significant digits" in notes
