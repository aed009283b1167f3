"""The estimator's error model: what the solve's evidence on the field's coefficients is worth.

The solve's likelihood treats edge points as independent; on real frames they are not (a scene edge is seen in many
frames, its points share its own curvature) and scenes add an apparent field of their own. Two terms replace it:

* the robust (sandwich) information H M⁻¹ H of the solve, its meat M the score's spread over scene edges (tracks),
  so that one edge seen in fifty frames counts once, whatever the frames: this one shrinks with independent edges;
* a scene term D that does not shrink with frames: the scenery's apparent field and the file's own error. Neither
  its size nor its shape is known: D_k = φ² λ̄^(1−γ) λ_k^γ (λ_k the prior's variance of component k, λ̄ their mean;
  γ = 1 a field shaped like the lens's, γ = 0 one that reaches the fine components as much as the coarse ones) is
  integrated over a grid of φ from a floor up to
  PHI_MAX and of γ, each weighted by how well the library explains the reading under it. A reading no
  miscalibration of the prior explains (a scene's own field) thus widens its own uncertainty instead of collapsing
  onto the nearest draw, and the floor keeps the posterior over the library smooth in the reading (a kernel
  regression over the library: no reading rests on one draw).
* with a baseline, also the spread of its frames' own readings around their mean (Baseline.spread_in): how much a
  different view of this camera's scenery moves the reading, in the directions it moves it, scaled by α on a grid
  (SPREAD_SCALES) and integrated with the φ grid's terms. Scenery moves the combinations of components that
  straight edges determine poorly; a term shaped like the prior spends the ± on every direction alike.

The reading is then c_read ~ N(c, (H M⁻¹ H)⁻¹ + D); the posterior is over the library's draws c_i (the prior) and D.
Where even the most lenient term leaves the nearest draw far outside that model (its χ² above the K it would have:
blur, low light or a scene's bend beyond PHI_MAX), the model is wrong for these frames and the likelihood is tempered
by the dispersion χ²/K (a quasi-likelihood): the posterior widens instead of collapsing onto that draw.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from appdgen.detect.solve import Estimate

#: Fewer segments used by the solve than this: the reading abstains.
MIN_SEGMENTS = 8
#: The model-based information's share mixed into the meat: with few scene edges the meat alone is noisy.
MEAT_MIX = 0.25
#: φ's floor, in sds of the prior's mean variance: below what real sequences under their true files choose with a
#: baseline (the real-sets study); the likelihood chooses φ above it.
SCENE_FLOOR = 0.1
#: The largest scene term considered, prior sds: a larger one lets a grossly wrong belief explain its bend as scenery
#: (it reads "uncertain": at 2.0 the quick start's 3 % belief is flagged in 1 of 2 sequences), a smaller one cuts the ±
#: below the truth on real frames (at 1.5 the desk's truth without a baseline is covered for 78 % of beliefs, at 1.75
#: for 81 %; docs/studies/real-sets.md, 2026-12-07).
PHI_MAX = 1.75
PHI_STEPS = 9  # values of φ on a log grid from the floor to PHI_MAX (a log-uniform prior)
SHAPES = (0.0, 0.5, 1.0)  # values of γ (a uniform prior)
#: α of the baseline's spread term α²Σ (a log-uniform prior): on the real sets a grid reaching 2 helped the desk's
#: windows of 50, one ending at 0.3 did not, EuRoC's hovers were indifferent (docs/studies/real-sets.md, 2026-12-07).
SPREAD_SCALES = tuple(np.geomspace(0.1, 2.0, 7))


@dataclass(frozen=True)
class Likelihood:
    """log p(reading | c_i, D_m) (m, n) up to a constant, for the library's draws c_i and the scene terms D_m: the
    grid's (φ, γ) pairs (phis, shapes), then the baseline's spread terms (shape NaN, φ their equivalent in prior
    sds)."""

    phis: np.ndarray
    shapes: np.ndarray
    log: np.ndarray
    dispersion: float = 1.0  # the nearest draw's χ² / K under its most lenient term (at least 1): log is divided by it


def robust_information(est: Estimate) -> tuple[np.ndarray, np.ndarray]:
    """(J, b): the sandwich information H M⁻¹ H and H M⁻¹ g of the solve, M its meat clustered by scene edge
    (inflated by G/(G−1) for G edges) mixed with MEAT_MIX·H."""
    h, g = est.h, est.g
    tracks = max(est.tracks, 2)
    meat = (est.meat if est.meat is not None else h) * tracks / (tracks - 1) + MEAT_MIX * h
    meat = meat + 1e-9 * max(float(np.trace(meat)), 1e-300) * np.eye(len(g))
    hm = np.linalg.solve(meat, h).T  # H M⁻¹ (both symmetric)
    return hm @ h, hm @ g


def scene_terms(prior_var: np.ndarray, floor: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The grid's (φ, γ) pairs and their scene variances D (m, K), coefficient units (px²)."""
    phis = np.geomspace(floor, max(PHI_MAX, floor), PHI_STEPS)
    phi, shape = (a.ravel() for a in np.meshgrid(phis, SHAPES, indexing="ij"))
    mean = prior_var.mean()
    return phi, shape, phi[:, None] ** 2 * mean ** (1 - shape[:, None]) * prior_var[None] ** shape[:, None]


def spread_terms(prior_var: np.ndarray, floor: float, spread: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The baseline spread's terms α²Σ + the floor's D (m, K, K) and their φ (prior sds of the same mean variance)."""
    base = floor ** 2 * prior_var
    terms = np.array([a ** 2 * spread + np.diag(base) for a in SPREAD_SCALES])
    phis = np.sqrt(np.einsum("mkk->m", terms) / prior_var.sum())
    return phis, terms


def likelihood(est: Estimate, coefs: np.ndarray, prior_var: np.ndarray, floor: float,
               spread: np.ndarray | None = None) -> Likelihood:
    """The reading's likelihood of each library draw under each scene term: the grid's, and with a baseline's spread
    Σ (K, K; coefficient units, px²) its scaled terms."""
    j, b = robust_information(est)
    phi, shape, scene = scene_terms(prior_var, floor)
    terms = [np.diag(d) for d in scene]
    if spread is not None:
        spread_phi, spread_d = spread_terms(prior_var, floor, spread)
        phi, shape = np.r_[phi, spread_phi], np.r_[shape, np.full(len(spread_d), np.nan)]
        terms.extend(spread_d)
    log, nearest = zip(*(log_likelihood(j, b, coefs, d) for d in terms), strict=True)
    read_info = b @ np.linalg.lstsq(j, b, rcond=1e-12)[0]  # c_readᵀ J c_read, the χ² quad lacks (J may be singular)
    dispersion = max(1.0, (float(np.min(nearest)) + read_info) / len(b))
    return Likelihood(phi, shape, np.array(log) / dispersion, dispersion)


def log_likelihood(j: np.ndarray, b: np.ndarray, coefs: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, float]:
    """log N(c_read; c_i, J⁻¹ + D) of each draw c_i up to a constant, from the information J, b = J c_read, and the
    nearest draw's χ² (c_i − c_read)ᵀ(J⁻¹ + D)⁻¹(c_i − c_read) less c_readᵀ J c_read (the same for every D)."""
    d_inv = np.linalg.inv(d)
    k = np.linalg.solve(d_inv + j, np.column_stack([j, b]))  # (D⁻¹ + J)⁻¹ [J, b]
    s_inv, s_b = j - j @ k[:, :-1], b - j @ k[:, -1]  # (J⁻¹ + D)⁻¹ and its product with the reading
    log_det = np.linalg.slogdet(d_inv + j)[1] + np.linalg.slogdet(d)[1]  # log|D| + log|D⁻¹ + J|
    quad = np.einsum("ij,jk,ik->i", coefs, s_inv, coefs) - 2 * coefs @ s_b - b @ k[:, -1]
    return -0.5 * (quad + log_det), float(quad.min())
