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
