"""appdgen.detect.model.field_lookup, third order, against exact fields (a quadratic, a belief's rest) and OpenCV's
INTER_CUBIC."""
from __future__ import annotations

import cv2
import numpy as np

from appdgen.calib.defaults import default_calibration
from appdgen.detect.model import belief_crop, field_grid, field_lookup
from appdgen.geometry.bend import output_rest
from appdgen.geometry.crop import valid_region
from appdgen.synth import scale_calibration

CAMERA = scale_calibration(default_calibration("02"), 0.5)  # KITTI camera 02 at half size (696×256)


def test_the_lookup_is_exact_on_a_quadratic_out_to_the_grids_edges_and_reads_the_edge_off_it():
    rng = np.random.default_rng(5)
    gu, gv = field_grid(CAMERA)
    c = rng.normal(size=(3, 6, 2))

    def quadratic(u, v, k):
        x, y = u / 700.0, v / 250.0
        return np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], -1) @ c[k]

    uu, vv = np.meshgrid(gu, gv)
    fields = np.stack([quadratic(uu, vv, k) for k in range(3)])
    u = np.concatenate([rng.uniform(gu[0], gu[-1], 500), [gu[0], gu[-1], gu[0], gu[-1]]])
    v = np.concatenate([rng.uniform(gv[0], gv[-1], 500), [gv[0], gv[0], gv[-1], gv[-1]]])
    first, rest = field_lookup(gu, gv, fields, u, v)
    np.testing.assert_allclose(first, quadratic(u, v, 0), atol=1e-9)
    np.testing.assert_allclose(rest, np.stack([quadratic(u, v, k) for k in (1, 2)], 1), atol=1e-9)
    # Off the grid (a point mapped from another rectification) it reads the nearest edge, never a runaway cubic.
    off_u, off_v = np.array([gu[0] - 40.0, gu[-1] + 90.0, gu[3]]), np.array([gv[2], gv[-1] + 60.0, gv[0] - 25.0])
    edge_u, edge_v = np.clip(off_u, gu[0], gu[-1]), np.clip(off_v, gv[0], gv[-1])
    np.testing.assert_allclose(field_lookup(gu, gv, fields, off_u, off_v)[0], quadratic(edge_u, edge_v, 0),
                               atol=1e-9)


def test_the_lookup_follows_a_beliefs_exact_rest_between_nodes_closer_than_opencvs_cubic():
    belief = CAMERA.replace(k1=CAMERA.k1 * 0.7)
    gu, gv = field_grid(belief)
    uu, vv = np.meshgrid(gu, gv)
    rng = np.random.default_rng(6)
    u, v = rng.uniform(gu[0], gu[-1], 2000), rng.uniform(gv[0], gv[-1], 2000)
    # The rest is defined up to an affine map: fit nodes and points jointly, so both are the same one.
    rest = output_rest(CAMERA, valid_region(CAMERA), belief, belief_crop(belief, None),
                       np.concatenate([uu.ravel(), u]), np.concatenate([vv.ravel(), v]))
    nodes, exact = rest[:uu.size].reshape(uu.shape + (2,)), rest[uu.size:]
    assert np.hypot(*exact.T).mean() > 0.5  # a real field, not zeros

    def rms(lookup) -> float:
        return float(np.sqrt(np.mean(np.sum((lookup(gu, gv, nodes[None], u, v)[0] - exact) ** 2, 1))))

    assert rms(field_lookup) < 0.03 and rms(opencv_cubic) > 0.1  # 0.018 against 0.26 px


def opencv_cubic(grid_u, grid_v, fields, u, v):
    """OpenCV's INTER_CUBIC (a = -0.75, first order) on the same grid: what the lookup replaced."""
    mx = ((u - grid_u[0]) / (grid_u[1] - grid_u[0])).astype(np.float32).reshape(1, -1)
    my = ((v - grid_v[0]) / (grid_v[1] - grid_v[0])).astype(np.float32).reshape(1, -1)
    out = cv2.remap(fields[0].astype(np.float32), mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1, 2).astype(float), None
