"""Model adequacy (identify/estimator/adequacy.py): white tracker noise and a model error shared along each sweep are
told apart, and the covariance is scaled for what each of them does to a fitted parameter."""

from __future__ import annotations

import numpy as np

from identify.estimator.adequacy import assess

SWEEPS, PER_SWEEP = 40, 36
SIGMA = 1e-5  # m per axis, the declared tracker noise


def _location_fit(model_error: float, seed: int, white: float = 0.0) -> tuple[float, float, object]:
    """Rows = a per-sweep offset (the model error, ``model_error`` m per axis, shared by the sweep's rows) + white
    noise (SIGMA declared, ``white`` more undeclared, e.g. timestamp jitter); the fitted model is one 3D location
    (the mean). Returns (true variance of the fitted mean per axis, the variance the assessment implies for it,
    the assessment)."""
    rng = np.random.default_rng(seed)
    offsets = rng.normal(0.0, model_error, (SWEEPS, 3)) if model_error else np.zeros((SWEEPS, 3))
    noise = np.hypot(SIGMA, white)
    data = np.repeat(offsets, PER_SWEEP, axis=0) + rng.normal(0.0, noise, (SWEEPS * PER_SWEEP, 3))
    m = len(data)
    residuals = data - data.mean(axis=0)
    jac = np.broadcast_to(np.eye(3), (m, 3, 3)).copy()
    runs = [np.arange(s * PER_SWEEP, (s + 1) * PER_SWEEP) for s in range(SWEEPS)]
    a = assess(residuals, jac, np.full(m, -1), runs, 1.0, SIGMA)
    true_var = noise**2 / m + model_error**2 / SWEEPS
    implied = max(a.residual, SIGMA) ** 2 * a.inflation / m  # as identify/results/pipeline.py scales the covariance
    return true_var, implied, a


def test_a_model_error_shared_by_each_sweep_is_inflated_by_the_samples_per_sweep_and_the_noise_is_not():
    """Noise 0.01 mm and a per-sweep offset of 0.01 mm: the residuals' lag-1 correlation is only 0.5, but the
    offset's own is 1, so the mean's variance is (sigma² + 36 tau²) / m, 18.5x the white-noise formula (the
    residual-level AR(1) factor gave 3x). The implied variance must match within the sampling spread of tau²
    estimated from 40 sweeps x 3 axes (relative sd about 0.13; 3.5 sd allowed)."""
    ratios = []
    for seed in range(5):
        true_var, implied, a = _location_fit(SIGMA, seed)
        assert a.detected
        assert 0.5 < a.model_error / SIGMA < 1.5
        ratios.append(implied / true_var)
    assert all(0.55 < r < 1.45 for r in ratios), ratios


def test_white_noise_alone_is_not_inflated():
    for seed in range(3):
        true_var, implied, a = _location_fit(0.0, seed)
        assert not a.detected and a.inflation == 1.0
        assert 0.8 < implied / true_var < 1.2


def test_white_noise_beyond_the_declared_is_not_model_error():
    """Undeclared white noise (a streamed row's timestamp jitter times the TP speed) of 1.5x the declared noise and
    no model error: the excess is detected but uncorrelated, so it is not model error (which every prediction
    would add: the 2.2x pessimism of continuous sessions) and nothing is inflated."""
    for seed in range(5):
        true_var, implied, a = _location_fit(0.0, seed, white=1.5 * SIGMA)
        assert a.detected
        assert a.model_error < 0.2 * SIGMA and 1.3 < a.white / SIGMA < 1.7
        assert a.inflation < 1.05 and 0.8 < implied / true_var < 1.2


def test_model_error_and_white_excess_are_told_apart():
    """A per-sweep offset of SIGMA and undeclared white noise of 1.5 SIGMA: the model error is the offset's size,
    the white rest is the jitter's, and the implied variance of the mean matches its true variance."""
    ratios = []
    for seed in range(5):
        true_var, implied, a = _location_fit(SIGMA, seed, white=1.5 * SIGMA)
        assert 0.5 < a.model_error / SIGMA < 1.5 and 1.0 < a.white / SIGMA < 2.0
        ratios.append(implied / true_var)
    assert all(0.55 < r < 1.45 for r in ratios), ratios
