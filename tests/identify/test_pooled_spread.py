"""Rows whose sigma is the spread of their own few readings (a tracker that states none: I++, some serial profiles)
take the pooled spread (identify/io/session_measurements.py): weighing by the rows' own estimates as if known inflates
the fit's chi-square by ν/(ν−2) (1.2 for 5 readings, 12 dof), which made a right model warn; the pooled figure does
not."""

from __future__ import annotations

import numpy as np

from identify.io.session_measurements import pooled_spread

NOISE, SAMPLES, ROWS = 5e-5, 5, 4000  # m per axis per reading, readings per step, steps


def test_pooled_spread_removes_the_chi_square_bias_of_per_row_estimates() -> None:
    rng = np.random.default_rng(0)
    readings = rng.normal(0.0, NOISE, (ROWS, SAMPLES, 3))
    means = readings.mean(axis=1)  # a right model's residual: the average's own noise
    own = np.sqrt(np.mean(readings.var(axis=1, ddof=1), axis=1)) / np.sqrt(SAMPLES)  # what the orchestrator records
    samples = np.full(ROWS, float(SAMPLES))
    pooled = pooled_spread(own, samples, np.ones(ROWS, dtype=bool))
    raw_chi2 = np.mean(means**2 / own[:, None] ** 2)
    pooled_chi2 = np.mean(means**2 / pooled[:, None] ** 2)
    nu = 3 * (SAMPLES - 1)
    assert abs(raw_chi2 - nu / (nu - 2)) < 0.05  # 1.2: the bias the model check saw
    assert abs(pooled_chi2 - 1.0) < 0.03  # per axis, 12,000 values: a 1.3 % spread
    assert np.allclose(pooled, pooled[0]) and abs(pooled[0] * np.sqrt(SAMPLES) / NOISE - 1) < 0.01


def test_estimated_rows_of_two_or_more_readings_are_pooled_and_every_estimated_row_takes_it() -> None:
    sigma = np.array([1e-5, 3e-5, np.nan, 4e-5, 7e-5])
    samples = np.array([4.0, 4.0, 1.0, 2.0, 5.0])
    estimated = np.array([True, True, True, True, False])  # the last one's device stated its sigma
    out = pooled_spread(sigma, samples, estimated)
    dof = 3 * (samples[[0, 1, 3]] - 1)
    per_reading = np.sum(dof * samples[[0, 1, 3]] * sigma[[0, 1, 3]] ** 2) / np.sum(dof)
    np.testing.assert_allclose(out[:4], np.sqrt(per_reading / samples[:4]))  # one reading: no spread, the pooled
    assert out[4] == sigma[4]  # a device's figure stays
    assert pooled_spread(sigma, samples, np.zeros(5, dtype=bool)) is sigma
