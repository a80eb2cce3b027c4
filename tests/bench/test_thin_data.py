"""Issue 34: on ±20° arcs with no free poses the reported sigmas hold over noise draws, no draw writes a table of
metres and none passes with nothing held out (bench/thin_data.py, at a tenth of its draws)."""

from __future__ import annotations

from bench.thin_data import band, one_arm


def test_ur5e_short_arcs_sigmas_hold_over_ten_noise_draws():
    r = one_arm("ur5e", True, 2, 10, 8, 5e-5)  # the arm on which one draw in 40 wrote d2, d4 of ±119 m
    _, high = band(10)
    assert not r.outside and r.worst <= high
    assert r.statuses == {"warn": 10} and r.metres == 0 and r.failures == 0
    assert r.error < 2.0 * r.stated  # over the whole joint space, where the stated figure is a lower bound


def test_ur5e_short_arcs_with_six_dof_readings_determine_every_parameter_with_honest_sigmas():
    """Issue 35: ±20° arcs with 6-DoF readings (0.02 mm, 0.2 mrad per axis): every parameter determined in every draw,
    only the conventions a DH table always holds are fixed, and each one's spread over the draws (the target frame's
    turn included) lies within the band of its reported sigma."""
    r = one_arm("ur5e", False, 0, 10, 8, 2e-5, 2e-4)
    low, high = band(10)
    assert not r.outside and low <= min(v for _, v in r.ratios) and r.worst <= high
    assert {"frame.rx", "frame.ry", "frame.rz", "alpha5", "theta4"} <= {n for n, _ in r.ratios}
    assert r.determined == 10 and r.failures == 0 and r.metres == 0
    # the base places frame 0 (theta1, d1), the target frame places frame 6, axes 2-3-4 are parallel (d2, d3)
    assert {n for n, _ in r.fixed} == {"theta1", "d1", "d2", "d3", "theta6", "d6", "a6", "alpha6"}
    assert r.error < 1.3 * r.stated
