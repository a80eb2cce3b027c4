"""The outlier test (identify/estimator/outliers.py) on residuals with known structure: isolated gross errors go, an
error that moves the greater part of a sweep stays (it is the model's to show, not a beam break)."""

from __future__ import annotations

import numpy as np
import pytest

from identify.estimator.outliers import outlier_free

SIGMA = 5e-5  # m per axis
SWEEPS, SAMPLES = 6, 6


def _residuals(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.random.Generator]:
    rng = np.random.default_rng(seed)
    group = np.repeat(np.arange(1, SWEEPS + 1), SAMPLES)
    key = np.tile(np.linspace(-2.5, 2.5, SAMPLES), SWEEPS)  # the moved joint's value along each arc (rad)
    return rng.normal(0.0, SIGMA, (len(group), 3)), group, key, rng


def _away(rng: np.random.Generator, n: int, size: float) -> np.ndarray:
    """``n`` offsets of length ``size`` (m) in random directions: errors that do not follow the arc."""
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1)[:, None] * size


@pytest.mark.parametrize("seed", range(5))
def test_a_sweep_the_model_misses_as_a_whole_keeps_its_samples(seed: int) -> None:
    """An elastic joint's sweep of 6 samples over most of a turn: each sample 12-15 sigma off, in directions that
    do not follow the arc (too thinly sampled for the neighbour test). Before, 5 of its 6 samples were rejected
    and the joint lost its data (a fit at 827 mm on the ``elastic`` robustness case)."""
    res, group, key, rng = _residuals(seed)
    sweep = group == 4
    res[sweep] += _away(rng, SAMPLES, 1.0) * rng.uniform(12, 15, (SAMPLES, 1)) * SIGMA
    keep = outlier_free(res, np.zeros(len(res)), group, key)
    assert keep.all()


@pytest.mark.parametrize("seed", range(5))
def test_isolated_gross_errors_are_still_rejected(seed: int) -> None:
    """A beam break in each of two sweeps (5-20 mm) and two in a third: exactly those go."""
    res, group, key, rng = _residuals(seed)
    bad = np.array([1, 9, 20, 23])  # sweeps 1, 2 and 4 (two of its six)
    res[bad] += _away(rng, len(bad), 1.0) * rng.uniform(5e-3, 2e-2, (len(bad), 1))
    keep = outlier_free(res, np.zeros(len(res)), group, key)
    assert np.array_equal(np.flatnonzero(~keep), bad)


@pytest.mark.parametrize("seed", range(3))
def test_half_of_a_thin_sweep_is_never_rejected(seed: int) -> None:
    """A real FANUC arm's 4-sample sweeps lost 2 clean samples each to the beam-break test: a sweep never loses half
    of its samples; the error that moves them is the model's to show."""
    res, group, key, rng = _residuals(seed)
    sweep = np.flatnonzero(group == 4)[:4]
    thin = group.copy()
    thin[np.flatnonzero(group == 4)[4:]] = 0  # the sweep keeps 4 samples; its other rows become free poses
    res[sweep[:2]] += _away(rng, 2, 1.0) * 15 * SIGMA
    keep = outlier_free(res, np.zeros(len(res)), thin, key)
    assert keep[sweep].all()
