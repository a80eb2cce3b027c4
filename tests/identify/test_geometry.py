"""Property-based tests of identify/estimator/geometry.py: plane, line and circle fits, common normal, rotations.

Noiseless cases are checked to ~1e-9 (exact geometry up to rounding); noisy cases against tolerances derived
from the noise level (a few standard deviations of the estimator), never "it ran".
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from identify.estimator.geometry import (
    Circle,
    angles_on_circle,
    circle_2d_algebraic,
    circle_from_points,
    circle_residuals,
    common_normal,
    line_from_points,
    perpendicular_basis,
    plane_from_points,
    rotation_about_axis,
    unit,
)

FAST = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])

coordinate = st.floats(-2.0, 2.0, allow_nan=False, allow_infinity=False)
points3 = st.tuples(coordinate, coordinate, coordinate).map(np.array)
raw_vectors = st.tuples(*(st.floats(-1.0, 1.0, allow_nan=False),) * 3).map(np.array)
unit_vectors = raw_vectors.filter(lambda v: np.linalg.norm(v) > 0.1).map(unit)
seeds = st.integers(0, 2**32 - 1)


def in_plane_basis(normal: np.ndarray, turn: float) -> tuple[np.ndarray, np.ndarray]:
    """A right-handed in-plane basis (e1, e2) about ``normal``, turned by ``turn`` rad from perpendicular_basis's
    (so the tests do not only see the library's own choice of basis)."""
    b1, b2 = perpendicular_basis(normal)
    return np.cos(turn) * b1 + np.sin(turn) * b2, -np.sin(turn) * b1 + np.cos(turn) * b2


def arc_points(centre, normal, radius, start, span, m, turn=0.3):
    """``m`` points on a circle, counter-clockwise about ``normal`` from angle ``start`` over ``span`` rad."""
    e1, e2 = in_plane_basis(normal, turn)
    t = start + np.linspace(0.0, span, m)
    return centre + radius * (np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2)


def same_axis(u: np.ndarray, v: np.ndarray) -> float:
    """1 - |cos angle| between two directions (0 when parallel or antiparallel)."""
    return 1.0 - abs(float(unit(u) @ unit(v)))


def distance_to_line(x, point, direction) -> float:
    rel = np.asarray(x) - point
    return float(np.linalg.norm(rel - (rel @ direction) * direction))


# --- plane and line -----------------------------------------------------------------------------------------


@FAST
@given(centre=points3, normal=unit_vectors, seed=seeds, m=st.integers(3, 40))
def test_plane_from_points_recovers_a_noiseless_plane(centre, normal, seed, m):
    rng = np.random.default_rng(seed)
    e1, e2 = perpendicular_basis(normal)
    uv = rng.uniform(-1.0, 1.0, size=(m, 2))
    assume(np.linalg.matrix_rank(uv - uv.mean(axis=0), tol=1e-3) == 2)  # not collinear
    pts = centre + uv[:, :1] * e1 + uv[:, 1:] * e2
    plane = plane_from_points(pts)
    assert same_axis(plane.normal, normal) < 1e-12
    assert np.linalg.norm(plane.normal) == pytest.approx(1.0, abs=1e-12)
    assert abs((plane.centroid - centre) @ normal) < 1e-12
    assert plane.rms < 1e-12


@FAST
@given(point=points3, direction=unit_vectors, seed=seeds, m=st.integers(2, 40))
def test_line_from_points_recovers_a_noiseless_line(point, direction, seed, m):
    rng = np.random.default_rng(seed)
    t = rng.uniform(-1.0, 1.0, m)
    assume(np.ptp(t) > 1e-3)
    pts = point + t[:, None] * direction
    line = line_from_points(pts)
    assert same_axis(line.direction, direction) < 1e-12
    assert np.linalg.norm(line.direction) == pytest.approx(1.0, abs=1e-12)
    assert distance_to_line(line.point, point, direction) < 1e-12
    assert line.rms < 1e-12


def test_plane_and_line_rms_measure_the_scatter():
    """The rms is the RMS point distance: points at +-h off a plane (line) give rms = h."""
    h = 0.01
    plane = plane_from_points([[0, 0, h], [1, 0, -h], [0, 1, -h], [1, 1, h]])
    assert plane.rms == pytest.approx(h, rel=1e-12)
    line = line_from_points([[0, h, 0], [0, -h, 0], [3, 0, h], [3, 0, -h]])
    assert line.rms == pytest.approx(h, rel=1e-12)


# --- circle ---------------------------------------------------------------------------------------------------


@settings(max_examples=80, deadline=None)
@given(
    centre=points3,
    normal=unit_vectors,
    radius=st.floats(0.02, 1.0),
    span_deg=st.floats(10.0, 360.0),
    start=st.floats(0.0, 2 * np.pi),
    turn=st.floats(0.0, 2 * np.pi),
    m=st.integers(3, 60),
)
def test_circle_from_points_is_exact_on_noiseless_arcs(centre, normal, radius, span_deg, start, turn, m):
    span = np.radians(span_deg)
    if span_deg >= 359.0:  # a full turn: no repeated point
        span = 2 * np.pi * (1 - 1 / m)
    pts = arc_points(centre, normal, radius, start, span, m, turn)
    circle = circle_from_points(pts)
    assert np.linalg.norm(circle.center - centre) / radius < 1e-9
    assert abs(circle.radius - radius) / radius < 1e-9
    assert same_axis(circle.normal, normal) < 1e-12
    assert circle.rms / radius < 1e-9
    assert np.max(circle_residuals(pts, circle)) / radius < 1e-9


@settings(max_examples=60, deadline=None)
@given(
    centre=points3,
    normal=unit_vectors,
    radius=st.floats(0.02, 1.0),
    sigma=st.floats(1e-5, 5e-4),
    m=st.integers(8, 72),
    seed=seeds,
)
def test_circle_radius_error_on_a_full_circle_is_within_noise(centre, normal, radius, sigma, m, seed):
    """Full turn, m equally spaced samples, isotropic noise sigma per axis: the radius estimate has standard
    deviation sigma/sqrt(m) (the radial residuals average); allow 5 of them (plus the O(sigma^2/R) bias)."""
    rng = np.random.default_rng(seed)
    pts = arc_points(centre, normal, radius, 0.0, 2 * np.pi * (1 - 1 / m), m)
    pts = pts + rng.normal(0.0, sigma, pts.shape)
    circle = circle_from_points(pts)
    tol = 5.0 * sigma / np.sqrt(m) + sigma**2 / radius
    assert abs(circle.radius - radius) < tol
    # the centre: per in-plane coordinate sqrt(2/m) sigma, along the normal sigma/sqrt(m)
    assert np.linalg.norm(circle.center - centre) < 5.0 * sigma * np.sqrt(5.0 / m)
    # rms of 3D distances ~ sigma*sqrt(2) (radial + out of plane) less the fitted degrees of freedom
    assert 0.3 * sigma < circle.rms < 2.5 * sigma


def _crb_radius_std(radius: float, angles: np.ndarray, sigma: float) -> float:
    """Cramér-Rao standard deviation of the radius of a planar circle (centre x, y and radius unknown)."""
    jac = np.column_stack([-np.cos(angles), -np.sin(angles), -np.ones_like(angles)])
    return float(sigma * np.sqrt(np.linalg.inv(jac.T @ jac)[2, 2]))


@pytest.mark.parametrize(("radius", "sigma", "m"), [(0.3, 1e-4, 40), (0.1, 1e-4, 20), (0.05, 5e-5, 36)])
def test_geometric_circle_fit_is_unbiased_on_a_short_arc(radius, sigma, m):
    """+-20 deg arc: over many noise draws the geometric fit's mean radius error is within 4 standard errors
    of zero, and its spread is close to the Cramér-Rao bound (within 25 %). (Kåsa-type algebraic fits shrink
    the radius here; the Taubin seed is better but only the geometric fit is claimed unbiased.)"""
    rng = np.random.default_rng(20240601)
    draws = 300
    angles = np.radians(np.linspace(-20.0, 20.0, m))
    errors, seed_errors = np.empty(draws), np.empty(draws)
    for k in range(draws):
        centre = rng.uniform(-1, 1, 3)
        normal = unit(rng.normal(size=3))
        start = rng.uniform(0, 2 * np.pi)
        pts = arc_points(centre, normal, radius, start - np.radians(20.0), np.radians(40.0), m)
        pts = pts + rng.normal(0.0, sigma, pts.shape)
        errors[k] = circle_from_points(pts).radius - radius
        plane = plane_from_points(pts)
        e1, e2 = perpendicular_basis(plane.normal)
        rel = pts - plane.centroid
        seed_errors[k] = circle_2d_algebraic(np.column_stack([rel @ e1, rel @ e2]))[1] - radius
    crb = _crb_radius_std(radius, angles, sigma)
    assert abs(errors.mean()) < 4.0 * errors.std() / np.sqrt(draws)
    assert 0.8 * crb < errors.std() < 1.25 * crb
    # the seed is in the same ballpark (sanity of the comparison, not a claim of unbiasedness)
    assert seed_errors.std() < 2.0 * crb


@settings(max_examples=40, deadline=None)
@given(
    radius=st.floats(0.05, 1.0),
    sigma=st.floats(1e-5, 2e-4),
    outliers=st.integers(1, 3),
    size=st.floats(2e-3, 1e-2),
    span_deg=st.sampled_from([360.0, 180.0]),
    seed=seeds,
)
def test_robust_circle_fit_ignores_a_few_gross_outliers(radius, sigma, outliers, size, span_deg, seed):
    """36 samples, 1-3 of them off by 2-10 mm: with robust_scale = sigma the fit stays within a few sigma,
    where a plain least-squares fit is pulled by the outliers."""
    rng = np.random.default_rng(seed)
    m = 36
    centre = rng.uniform(-2, 2, 3)
    normal = unit(rng.normal(size=3))
    span = 2 * np.pi * (1 - 1 / m) if span_deg == 360.0 else np.radians(span_deg)
    pts = arc_points(centre, normal, radius, rng.uniform(0, 2 * np.pi), span, m)
    pts = pts + rng.normal(0.0, sigma, pts.shape)
    bad = rng.choice(m, outliers, replace=False)
    pts[bad] += unit(rng.normal(size=(outliers, 3))) * size
    circle = circle_from_points(pts, robust_scale=sigma)
    scale = sigma / np.sqrt(m - outliers)
    if span_deg == 360.0:
        assert abs(circle.radius - radius) < 6.0 * scale
        assert np.linalg.norm(circle.center - centre) < 6.0 * scale * np.sqrt(5.0)
    else:  # a half turn: the radius and centre are correlated, allow twice as much
        assert abs(circle.radius - radius) < 12.0 * scale
        assert np.linalg.norm(circle.center - centre) < 12.0 * scale * np.sqrt(5.0)
    assert np.arccos(min(1.0, abs(circle.normal @ normal))) * radius < 6.0 * scale * np.sqrt(5.0)


def test_plain_circle_fit_is_pulled_by_outliers_that_the_robust_fit_ignores():
    """The robust test above can fail: the same data without robust_scale is visibly off."""
    rng = np.random.default_rng(7)
    m, radius, sigma = 36, 0.2, 5e-5
    centre, normal = np.array([0.5, -0.3, 1.2]), unit([0.2, 0.3, 1.0])
    pts = arc_points(centre, normal, radius, 0.0, 2 * np.pi * (1 - 1 / m), m)
    pts = pts + rng.normal(0.0, sigma, pts.shape)
    pts[[3, 17, 30]] += np.array([[5e-3, 0, 0], [0, 5e-3, 0], [0, 0, 5e-3]])
    plain = circle_from_points(pts)
    robust = circle_from_points(pts, robust_scale=sigma)
    plain_error = np.linalg.norm(plain.center - centre) + abs(plain.radius - radius)
    robust_error = np.linalg.norm(robust.center - centre) + abs(robust.radius - radius)
    assert plain_error > 20 * sigma / np.sqrt(m)
    assert robust_error < 10 * sigma / np.sqrt(m)


# --- angles on a circle ---------------------------------------------------------------------------------------


@FAST
@given(
    centre=points3,
    normal=unit_vectors,
    radius=st.floats(0.02, 1.0),
    start=st.floats(-np.pi, np.pi),
    turn=st.floats(0.0, 2 * np.pi),
    steps=st.lists(st.floats(0.01, 3.0), min_size=1, max_size=30),
)
def test_angles_on_circle_increase_counter_clockwise(centre, normal, radius, start, turn, steps):
    """Points turning counter-clockwise about the normal (right-hand rule) get increasing, unwrapped
    angles whose differences are the turns between them; the reversed normal reverses them."""
    t = start + np.concatenate([[0.0], np.cumsum(steps)])
    e1, e2 = in_plane_basis(normal, turn)
    pts = centre + radius * (np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2)
    circle = Circle(centre, normal, radius, 0.0)
    angles = angles_on_circle(pts, circle)
    assert np.all(np.diff(angles) > 0)
    np.testing.assert_allclose(np.diff(angles), np.diff(t), atol=1e-9)
    reverse = angles_on_circle(pts, Circle(centre, -normal, radius, 0.0))
    np.testing.assert_allclose(np.diff(reverse), -np.diff(t), atol=1e-9)


# --- common normal ----------------------------------------------------------------------------------------------


def _check_feet(cn, p1, u1, p2, u2, tol=1e-9):
    assert distance_to_line(cn.foot_1, p1, u1) < tol
    assert distance_to_line(cn.foot_2, p2, u2) < tol


@settings(max_examples=60, deadline=None)
@given(p1=points3, u1=unit_vectors, p2=points3, u2=unit_vectors, s=coordinate, t=coordinate)
def test_common_normal_of_skew_lines(p1, u1, p2, u2, s, t):
    assume(np.linalg.norm(np.cross(u1, u2)) > 0.05)  # well away from parallel
    cn = common_normal(p1, u1, p2, u2)
    assert not cn.parallel
    _check_feet(cn, p1, u1, p2, u2)
    segment = cn.foot_2 - cn.foot_1
    assert abs(segment @ u1) < 1e-9
    assert abs(segment @ u2) < 1e-9
    # the shortest connection: no pair of points on the two lines is closer
    other = np.linalg.norm((p2 + t * u2) - (p1 + s * u1))
    assert cn.length <= other + 1e-12
    # the textbook distance |(p2 - p1) . (u1 x u2)| / |u1 x u2|
    n = np.cross(u1, u2)
    assert cn.length == pytest.approx(abs((p2 - p1) @ n) / np.linalg.norm(n), abs=1e-9)
    # symmetric under swapping the lines (and under flipping a direction)
    swapped = common_normal(p2, u2, p1, u1)
    assert swapped.length == pytest.approx(cn.length, abs=1e-9)
    np.testing.assert_allclose(swapped.foot_1, cn.foot_2, atol=1e-9)
    np.testing.assert_allclose(swapped.foot_2, cn.foot_1, atol=1e-9)
    flipped = common_normal(p1, -u1, p2, u2)
    np.testing.assert_allclose(flipped.foot_1, cn.foot_1, atol=1e-9)


@FAST
@given(x=points3, u1=unit_vectors, u2=unit_vectors, s=coordinate, t=coordinate)
def test_common_normal_of_intersecting_lines_has_zero_length(x, u1, u2, s, t):
    assume(np.linalg.norm(np.cross(u1, u2)) > 0.05)
    p1, p2 = x + s * u1, x + t * u2  # both lines pass through x
    cn = common_normal(p1, u1, p2, u2)
    assert cn.length < 1e-9
    np.testing.assert_allclose(cn.foot_1, x, atol=1e-9)
    np.testing.assert_allclose(cn.foot_2, x, atol=1e-9)


@FAST
@given(
    p1=points3,
    u=unit_vectors,
    offset=raw_vectors,
    sign=st.sampled_from([1.0, -1.0]),
    anchor_at=st.one_of(st.none(), coordinate),
    tilt=st.sampled_from([0.0, 1e-7, 1e-4]),
)
def test_common_normal_of_parallel_lines_passes_through_the_anchor(p1, u, offset, sign, anchor_at, tilt):
    """Parallel (or antiparallel) lines, or lines within ``parallel_tol`` of it: the normal starts at the anchor
    (p1 by default) and ends at its projection onto line 2."""
    p2 = p1 + offset
    e1, _ = perpendicular_basis(u)
    u2 = unit(sign * u + tilt * e1)
    anchor = None if anchor_at is None else p1 + anchor_at * u
    cn = common_normal(p1, u, p2, u2, parallel_tol=1e-3, anchor=anchor)
    assert cn.parallel
    expected_1 = p1 if anchor is None else anchor
    np.testing.assert_allclose(cn.foot_1, expected_1, atol=1e-12)
    np.testing.assert_allclose(cn.foot_2, p2 + ((expected_1 - p2) @ u2) * u2, atol=1e-12)
    assert abs((cn.foot_2 - cn.foot_1) @ u2) < 1e-11
    if tilt == 0.0:  # exactly parallel: the length is the distance between the lines, either way round
        assert cn.length == pytest.approx(distance_to_line(p2, p1, u), abs=1e-12)
        assert common_normal(p2, u2, p1, u, parallel_tol=1e-3).length == pytest.approx(cn.length, abs=1e-12)


def test_common_normal_parallel_tol_decides_between_the_conventions():
    """A 1e-4 rad tilt is parallel for a 1e-3 tolerance and skew (the unique normal, far away) for 1e-6."""
    p1, u1 = np.zeros(3), np.array([0.0, 0.0, 1.0])
    p2, u2 = np.array([0.1, 0.0, 0.0]), unit([1e-4, 0.0, 1.0])
    loose = common_normal(p1, u1, p2, u2, parallel_tol=1e-3)
    strict = common_normal(p1, u1, p2, u2, parallel_tol=1e-6)
    assert loose.parallel and not strict.parallel
    np.testing.assert_allclose(loose.foot_1, p1, atol=1e-15)
    assert strict.length == pytest.approx(0.0, abs=1e-9)  # these two lines happen to intersect ...
    assert abs(strict.foot_1[2]) > 100.0  # ... about 1 km away along the axes


# --- rotations ----------------------------------------------------------------------------------------------------


@FAST
@given(axis=raw_vectors.filter(lambda v: np.linalg.norm(v) > 0.1), a=st.floats(-10, 10), b=st.floats(-10, 10))
def test_rotation_about_axis(axis, a, b):
    rot = rotation_about_axis(axis, a)
    np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-12)
    assert np.linalg.det(rot) == pytest.approx(1.0, abs=1e-12)
    k = unit(axis)  # the axis need not be given unit length
    np.testing.assert_allclose(rot @ k, k, atol=1e-12)
    np.testing.assert_allclose(rotation_about_axis(axis, b) @ rot, rotation_about_axis(axis, a + b), atol=1e-12)
    np.testing.assert_allclose(rotation_about_axis(axis, -a), rot.T, atol=1e-12)
    # counter-clockwise (right-hand rule): a vector perpendicular to the axis turns towards k x v
    v, _ = perpendicular_basis(k)
    np.testing.assert_allclose(rot @ v, np.cos(a) * v + np.sin(a) * np.cross(k, v), atol=1e-12)


def test_rotation_about_axis_broadcasts_over_angles():
    angles = np.array([0.0, np.pi / 2, np.pi])
    rots = rotation_about_axis([0.0, 0.0, 2.0], angles)
    assert rots.shape == (3, 3, 3)
    np.testing.assert_allclose(rots[1] @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(rots[2] @ [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], atol=1e-15)
