"""ISO 9283 beyond AP/RP (identify/applications/iso9283.py): vAP per pose, orientation AP/RP from a rigid fit, and the
Monte-Carlo uncertainty of every figure against the spread of simulated repeats of the test."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from identify.applications.iso9283 import (
    accuracy,
    deviation_angles,
    directions_result,
    fitted_rotation,
    monte_carlo,
    orientation_result,
)

MM = 1e-3


def test_vap_and_orientation_follow_iso_9283_by_hand() -> None:
    # three directions: barycentres (0, 0, 0), (3, 4, 0) and (0, 0, 1) mm -> vAP = max(5, 1, sqrt(26)) mm
    sets = [np.array([[-1, 0, 0], [1, 0, 0]]) * MM, np.array([[3, 4, 0]]) * MM,
            np.array([[0, 0, 1], [0, 0, 2], [0, 0, 0]]) * MM]
    d = directions_result(2, sets)
    assert d.vap == pytest.approx(np.sqrt(26) * MM, rel=1e-12) and d.n == 1
    np.testing.assert_allclose(d.barycentres[2], [0, 0, MM], atol=1e-15)
    # three points on a plate turned by 2 mrad about x then 1 mrad about z (fixed axes) and shifted
    plate = np.array([[0.0, 0, 0], [0.2, 0, 0], [0, 0.15, 0.01]])
    turn = Rotation.from_euler("xyz", [2e-3, 0, 1e-3])
    moved = turn.apply(plate) + np.array([0.5, -0.2, 0.3])
    np.testing.assert_allclose(fitted_rotation(plate, moved), turn.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(deviation_angles(plate, moved), [2e-3, 0, 1e-3], atol=1e-12)
    # a reflection is not a rotation: the fit keeps det = +1
    assert np.linalg.det(fitted_rotation(plate, plate * [1, 1, -1])) == pytest.approx(1.0)
    # AP_a = mean a, RP_a = 3 S_a: a = 1, 2, 3 mrad -> 2 mrad and 3 mrad; b = 0 -> 0; c = -1, -1, -4 -> -2, 3 * sqrt(3)
    o = orientation_result(1, np.array([[1, 0, -1], [2, 0, -1], [3, 0, -4]]) * MM)
    np.testing.assert_allclose(o.ap, [2 * MM, 0, -2 * MM], atol=1e-15)
    np.testing.assert_allclose(o.rp, [3 * MM, 0, 3 * np.sqrt(3) * MM], rtol=1e-12, atol=1e-15)
    with pytest.raises(ValueError, match="at least 2 visits"):
        orientation_result(1, np.zeros((1, 3)))


def _figures(sets: dict) -> dict[str, float]:
    """AP and RP of P1 (direction 0), vAP of P1 over three directions, AP_a and RP_a of P1's orientation."""
    acc = accuracy("x", np.zeros((5, 3)), {1: sets[(1, 0)]})
    out = {"ap": acc.poses[0].ap, "rp": acc.poses[0].rp,
           "vap": directions_result(1, [sets[(1, h)] for h in range(3)]).vap}
    o = orientation_result(1, sets["abc"])
    return {**out, "ap_a": float(o.ap[0]), "rp_a": float(o.rp[0])}


@pytest.mark.slow
def test_monte_carlo_uncertainty_matches_the_spread_of_repeats() -> None:
    """The stated uncertainty (Monte-Carlo from one run's visits) against the standard deviation of each figure over
    independent simulated runs. With 150 runs the spread itself is known to 1/sqrt(298) = 5.8 %: 20 % is 3.4
    standard errors. The true offsets (0.5 mm AP, 0.2 mm between directions, 0.3 mrad) are far above the noise of a
    barycentre (0.05 mm / sqrt(30)), where AP and vAP are unbiased."""
    rng = np.random.default_rng(7)
    noise, n, runs = 5e-5, 30, 150
    centres = {(1, 0): np.array([0.5, 0, 0]) * MM, (1, 1): np.array([0.5, 0.2, 0]) * MM,
               (1, 2): np.array([0.5, 0, 0.1]) * MM}
    seen: dict[str, list[float]] = {}
    stated: dict[str, list[float]] = {}
    for run in range(runs):
        sets = {k: c + rng.normal(0, noise, (n, 3)) for k, c in centres.items()}
        sets["abc"] = np.array([3e-4, 0, 0]) + rng.normal(0, 1e-4, (n, 3))
        for name, value in _figures(sets).items():
            seen.setdefault(name, []).append(value)
        noises = {k: noise for k in centres} | {"abc": 0.0}
        groups = {k: 0 for k in centres} | {"abc": 1}
        for name, value in monte_carlo(_figures, sets, noises, draws=100, seed=run, groups=groups).items():
            stated.setdefault(name, []).append(value)
    for name in seen:
        spread, claim = np.std(seen[name], ddof=1), np.mean(stated[name])
        assert claim == pytest.approx(spread, rel=0.2), name


def test_monte_carlo_never_states_less_than_the_noise_allows() -> None:
    """Two visits that happen to agree do not make AP exact: the stated noise, worth two visits, holds the spread up
    (the group's covariance is (0 + 2 sigma²) / (1 + 2), the set's (0 + 10 x that) / (1 + 10))."""
    sets = {1: np.array([[1.0, 0, 0], [1.0, 0, 0]]) * MM}

    def figures(s: dict) -> dict[str, float]:
        return {"ap": accuracy("x", np.zeros((5, 3)), s).poses[0].ap}

    u = monte_carlo(figures, sets, {1: 5e-5}, draws=400)["ap"]
    assert u == pytest.approx(5e-5 * np.sqrt(20 / 33) / np.sqrt(2), rel=0.15)  # the barycentre's, along the offset
    assert monte_carlo(figures, sets, {1: 0.0}, draws=50)["ap"] == 0.0


def test_spread_covariances_pool_the_poses_of_a_group_by_hand() -> None:
    """Two sets of one group, three visits each along x (sample variances 1 and 4 mm², 2 dof each), no noise: the
    group's is 2.5 mm²; each set's (2 own + 10 group) / 12; a third set in a group of its own keeps its own."""
    from identify.applications.iso9283 import spread_covariances

    sets = {"a": np.array([[-1, 0, 0], [0, 0, 0], [1, 0, 0]]) * MM,
            "b": np.array([[-2, 0, 0], [0, 0, 0], [2, 0, 0]]) * MM,
            "c": np.array([[0, -1, 0], [0, 1, 0], [0, 0, 0]]) * MM}
    cov = spread_covariances(sets, {}, {"a": 1, "b": 1, "c": 2})
    assert cov["a"][0, 0] == pytest.approx((2 * 1 + 10 * 2.5) / 12 * MM**2, rel=1e-12)
    assert cov["b"][0, 0] == pytest.approx((2 * 4 + 10 * 2.5) / 12 * MM**2, rel=1e-12)
    assert cov["c"][1, 1] == pytest.approx(1 * MM**2, rel=1e-12) and cov["c"][0, 0] == 0.0
