"""The appd and rectify commands, and --max-fov / model parameter names on every geometry command."""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from appdgen.calib.calibration import Calibration
from appdgen.calib.formats import save
from appdgen.cli import main
from appdgen.errors import AppdgenError
from appdgen.geometry.appd import appd
from appdgen.geometry.distortion import distort_to_pixels
from appdgen.geometry.maps import rectify

SMALL = (160, 120)
#: One undistorted 640×480 pinhole camera (HFOV ≈ 77°), written in three lens models that reduce to it exactly:
#: radtan with no distortion, double sphere with ξ = α = 0, EUCM with α = 0 (β = 1).
PINHOLE = Calibration(640, 480, 400.0, 400.0, 319.5, 239.5)
AS_DS = Calibration(640, 480, 400.0, 400.0, 319.5, 239.5, model="ds", xi=0.0, alpha=0.0)
AS_EUCM = Calibration(640, 480, 400.0, 400.0, 319.5, 239.5, model="eucm", alpha=0.0, beta=1.0)
#: A wide fisheye (HFOV ≈ 160°) to bound with --max-fov.
FISHEYE = Calibration(640, 480, 160.0, 160.0, 319.5, 239.5, -0.01, 0.04, -0.04, 0.008, model="kb4")


def run(*args: object):
    """Invoke the appdgen CLI in-process."""
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def ok_json(*args: object) -> dict:
    """The JSON a successful command printed."""
    result = run(*args)
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)


def one_line_error(result, *fragments: str) -> None:
    """Assert an `appdgen: error:` line naming every fragment, exit status 2, nothing on stdout."""
    assert result.exit_code == 2, result.output
    assert result.stdout == "" and result.stderr.count("\n") == 1 and result.stderr.startswith("appdgen: error:")
    for fragment in fragments:
        assert fragment in result.stderr, result.stderr


@pytest.fixture
def files(tmp_path: Path) -> dict[str, Path]:
    """The calibrations above as appdgen JSON files."""
    paths = {}
    for name, calib in (("pinhole", PINHOLE), ("ds", AS_DS), ("eucm", AS_EUCM), ("fisheye", FISHEYE)):
        paths[name] = tmp_path / f"{name}.json"
        save(calib, paths[name])
    return paths


# --- appd --------------------------------------------------------------------------------------------------------


def test_appd_json_names_the_model_and_its_parameters(files):
    out = ok_json("appd", "--calib", files["fisheye"], "--perturb", "k4=0.1", "--size", "160x120", "--json",
                  "--max-fov", "120")
    for side, calib in (("reference", FISHEYE), ("perturbed", FISHEYE.perturb(k4=0.1))):
        assert list(out[side]) == ["model", "fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4", "size",
                                   "new_camera_matrix"]
        assert out[side]["model"] == "kb4" and out[side]["k4"] == calib.k4
    assert out["max_fov"] == 120.0
    expected, _ = appd(FISHEYE, FISHEYE.perturb(k4=0.1), SMALL, max_fov=120)
    assert out["appd_px"] == expected > 0


def test_appd_radtan_json_keeps_its_nine_parameters(files):
    out = ok_json("appd", "--calib", files["pinhole"], "--set", "k1=-0.05", "--json", "--size", "160x120")
    assert list(out["perturbed"]) == ["model", "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "size",
                                      "new_camera_matrix"]
    assert out["perturbed"]["model"] == "radtan" and "max_fov" not in out


@pytest.mark.parametrize("other", ["ds", "eucm"])
def test_appd_across_models_of_one_lens_is_zero(files, other):
    # The same pinhole camera in two models: the maps agree to float32 rounding.
    out = ok_json("appd", "--calib", files["pinhole"], "--against", files[other], "--json", "--size", "160x120")
    assert out["reference"]["model"] == "radtan" and out["perturbed"]["model"] == other
    assert out["appd_px"] < 1e-4
    np.testing.assert_allclose(out["perturbed"]["new_camera_matrix"], out["reference"]["new_camera_matrix"],
                               rtol=1e-9)


def test_appd_across_models_with_set_takes_the_second_models_names(files):
    out = ok_json("appd", "--calib", files["pinhole"], "--against", files["ds"], "--set", "alpha=0.1", "--json",
                  "--size", "160x120")
    expected, _ = appd(PINHOLE, AS_DS.replace(alpha=0.1), SMALL)
    assert out["perturbed"]["alpha"] == 0.1 and out["appd_px"] == pytest.approx(expected, rel=1e-12)
    assert out["appd_px"] > 1.0


def test_max_fov_bounds_reference_and_perturbed_alike(files):
    # fx, fy and centre as K̂ bounds |x| <= tan(FOV/2): both crops are the FOV box, so one K̂ serves both.
    out = ok_json("appd", "--calib", files["pinhole"], "--perturb", "fx=-0.05", "--max-fov", "60", "--json",
                  "--size", "160x120")
    expected_fx = 160 / (2 * math.tan(math.radians(30)))
    for side in ("reference", "perturbed"):
        assert out[side]["new_camera_matrix"][0][0] == pytest.approx(expected_fx, rel=1e-6)
    unbounded = ok_json("appd", "--calib", files["pinhole"], "--perturb", "fx=-0.05", "--json", "--size", "160x120")
    assert unbounded["reference"]["new_camera_matrix"][0][0] < expected_fx


@pytest.mark.parametrize(("args", "fragments"), [
    (["--max-fov", "0"], ["--max-fov", "0"]),
    (["--max-fov", "180"], ["--max-fov", "180"]),
    (["--max-fov", "wide"], ["--max-fov", "wide"]),
    (["--set", "p1=0.1"], ["--set 'p1=0.1'", "fx, fy, cx, cy, k1, k2, k3, k4", "kb4"]),
    (["--perturb", "xi=0.1"], ["--perturb 'xi=0.1'", "kb4"]),
])
def test_appd_bad_options_are_one_line(files, args, fragments):
    one_line_error(run("appd", "--calib", files["fisheye"], *args), *fragments)


def test_appd_against_another_raw_size_is_one_line(files, tmp_path):
    other = tmp_path / "other.json"
    save(AS_DS.replace(width=800), other)
    one_line_error(run("appd", "--calib", files["pinhole"], "--against", other), str(other), "800x480", "640x480")


def test_a_fisheye_seeing_180_degrees_needs_max_fov(files):
    # Its largest rectangle is unbounded: one line suggesting --max-fov, no traceback.
    one_line_error(run("appd", "--calib", files["fisheye"], "--json", "--size", "160x120"), "unbounded", "--max-fov")


# --- rectify -----------------------------------------------------------------------------------------------------


def test_rectify_with_max_fov_matches_the_library(files, tmp_path):
    raw = (np.indices((480, 640)).sum(axis=0) % 251).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "raw.png"), np.dstack([raw] * 3))
    out = tmp_path / "out.png"
    result = run("rectify", "--calib", files["fisheye"], "--max-fov", "100", "--size", "160x120",
                 "--interp", "nearest", tmp_path / "raw.png", "-o", out)
    assert result.exit_code == 0, result.output
    rect = rectify(FISHEYE, SMALL, max_fov=100)
    expected = cv2.remap(raw, rect.map_x, rect.map_y, cv2.INTER_NEAREST)
    np.testing.assert_array_equal(cv2.imread(str(out))[:, :, 0], expected)


# --- sweep, reproj, drift ------------------------------------------------------------------------------------------


def read_csv(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as stream:
        return list(csv.DictReader(stream))


def test_sweep_defaults_to_the_models_parameters(files, tmp_path):
    out = tmp_path / "sweep.csv"
    result = run("sweep", "--calib", files["fisheye"], "--steps", "3", "--size", "160x120", "--max-fov", "120",
                 "--csv", out)
    assert result.exit_code == 0, result.output
    assert list(read_csv(out)[0]) == ["t", *(f"appd_pct_{n}" for n in FISHEYE.param_names)]
    # ds with ξ = α = 0: both coefficients are 0, so only the intrinsics are swept (and the skips are noted).
    result = run("sweep", "--calib", files["ds"], "--steps", "3", "--size", "160x120", "--csv", out)
    assert "xi skipped" in result.stderr and "alpha skipped" in result.stderr
    assert list(read_csv(out)[0]) == ["t", "appd_pct_fx", "appd_pct_fy", "appd_pct_cx", "appd_pct_cy"]


def test_sweep_with_max_fov_matches_the_library(files):
    from appdgen.analysis.studies import sweep

    result = run("sweep", "--calib", files["fisheye"], "--params", "k2", "--from", "-0.1", "--to", "0.1",
                 "--steps", "3", "--size", "160x120", "--max-fov", "120")
    assert result.exit_code == 0, result.output
    expected = sweep(FISHEYE, ["k2"], np.array([-0.1, 0.0, 0.1]), SMALL, 120)["k2"]
    assert f"{expected[-1]:.4f}" in result.stdout.splitlines()[-1]


def test_reproj_samples_the_models_parameters(files, tmp_path):
    out = tmp_path / "reproj.csv"
    result = run("reproj", "--calib", files["fisheye"], "--samples", "6", "--points", "50", "--size", "160x120",
                 "--max-fov", "120", "--csv", out)
    assert result.exit_code == 0, result.output
    rows = read_csv(out)
    assert list(rows[0])[1:9] == [f"t_{n}" for n in FISHEYE.param_names]
    assert all(-0.15 <= float(row["t_k4"]) <= 0.15 for row in rows) and len({row["t_k4"] for row in rows}) == 6


def test_drift_across_models(files):
    table = ok_json("drift", files["pinhole"], files["ds"], files["eucm"], "--size", "160x120", "--json")
    assert np.array(table["cameras"]["0"]["appd_px"]).max() < 1e-4
    bounded = ok_json("drift", files["pinhole"], files["fisheye"], "--size", "160x120", "--max-fov", "70", "--json")
    expected, _ = appd(PINHOLE, FISHEYE, SMALL, max_fov=70)
    assert bounded["cameras"]["0"]["appd_px"][0][1] == pytest.approx(expected, rel=1e-12) and expected > 1


# --- a real fisheye against itself in another model -----------------------------------------------------------------


def fit_double_sphere(calib: Calibration, max_angle: float) -> Calibration:
    """The double-sphere calibration closest (least squares, pixels) to calib's projection of rays up to max_angle."""
    theta, phi = np.meshgrid(np.linspace(0.01, np.radians(max_angle), 40), np.linspace(0, 2 * np.pi, 72))
    x, y = (np.tan(theta) * np.cos(phi)).ravel(), (np.tan(theta) * np.sin(phi)).ravel()
    target = np.concatenate(distort_to_pixels(x, y, calib))
    # Start near a ~190° fisheye's double sphere: fx ≈ 0.83 of the Kannala–Brandt one, ξ ≈ −0.18, α ≈ 0.59.
    params = np.array([0.83 * calib.fx, 0.83 * calib.fy, calib.cx, calib.cy, -0.18, 0.59])

    def residual(p: np.ndarray) -> np.ndarray:
        ds = Calibration(calib.width, calib.height, *p[:4], model="ds", xi=p[4], alpha=p[5])
        return np.concatenate(distort_to_pixels(x, y, ds)) - target

    damping = 1e-3
    for _ in range(50):  # Levenberg–Marquardt, forward-difference Jacobian
        r = residual(params)
        steps = 1e-7 * np.maximum(np.abs(params), 1e-3)
        jac = np.stack([(residual(params + np.eye(6)[i] * steps[i]) - r) / steps[i] for i in range(6)], axis=1)
        normal = jac.T @ jac
        trial = params - np.linalg.solve(normal + damping * np.diag(np.diag(normal)), jac.T @ r)
        try:
            better = np.sum(residual(trial) ** 2) < np.sum(r ** 2)
        except AppdgenError:  # a step out of the model's domain (α > 1): damp harder
            better = False
        if better:
            params, damping = trial, damping / 3
        else:
            damping *= 4
    return Calibration(calib.width, calib.height, *params[:4], model="ds", xi=params[4], alpha=params[5])


def test_tumvi_kannala_brandt_against_a_fitted_double_sphere(shared, tmp_path):
    tumvi = shared / "formats" / "kalibr_tumvi_pinhole_equi.yaml"
    from appdgen.calib.formats import load

    ds = fit_double_sphere(load(tumvi, "cam0"), 60)
    save(ds, tmp_path / "tumvi_ds.json")
    out = ok_json("appd", "--calib", tumvi, "--camera", "cam0", "--against", tmp_path / "tumvi_ds.json",
                  "--max-fov", "120", "--json")
    assert (out["reference"]["model"], out["perturbed"]["model"]) == ("kb4", "ds")
    # One lens in two models (measured: ξ = −0.174, α = 0.593, 0.003 px apart), under a hundredth of what fx
    # 1 % off gives in the same model (1.26 px).
    assert ds.xi == pytest.approx(-0.18, abs=0.02) and ds.alpha == pytest.approx(0.59, abs=0.02)
    nudged = ok_json("appd", "--calib", tumvi, "--camera", "cam0", "--perturb", "fx=0.01", "--max-fov", "120",
                     "--json")
    assert out["appd_px"] < 0.01 * nudged["appd_px"]
