"""Every HTML page (the identification report with its run record, the verification report, the trend page) laid
out by headless Chromium at 1280 px: no horizontal scrolling of the page or of any element, and no text box over
another (each text node's boxes measured with ``Range.getClientRects``, tests/_page_layout.py). Chromium is a
system package, not a Python dependency of the project, so the test is skipped without it; the figures inside the
pages are checked on matplotlib's own renderer in test_figure_layout.py, which always runs. Before, the
verification report's per-pose table scrolled sideways (1329 px in a 1100 px column)."""

from __future__ import annotations

import pytest

pytest.importorskip("matplotlib")

from acquire.running.session import Session
from identify.applications.calibrated import CalibratedModel
from identify.applications.compare import compare
from identify.report.compare_html import compare_html
from identify.report.html import report_html
from identify.report.verify_html import verification_html
from tests._page_layout import CHROMIUM, page_layout
from tests.identify.report.test_html import _identified, session_path  # noqa: F401 (a fixture)

pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed")

WIDTH = 1280


def _fits(html: str, folder) -> None:
    layout = page_layout(html, folder, WIDTH)
    assert layout["scroll"] <= 0 and layout["sideways"] == [] and layout["overlaps"] == [], layout


@pytest.mark.slow
def test_the_identification_report(session_path, tmp_path):  # noqa: F811
    robot, meas, ident = _identified("ur5e")
    with Session.open(session_path) as session:
        _fits(report_html(ident, meas, robot.nominal, robot.name, session=session), tmp_path)


def test_the_verification_report(session_path, tmp_path):  # noqa: F811
    poses = {m: {"poses": [{"pose": f"P{k}", "ap": a * (1 + k / 10), "ap_std": 1e-6, "rp": 7e-5 + k * 5e-6,
                            "n": 10} for k in range(1, 6)], "ap_max": a * 1.5, "rp_max": 1e-4}
             for m, a in (("before", 1.523456e-3), ("after", 1.2345e-5))}
    summary = {"runs": poses, "predicted": {"before": [1.5e-3] * 5}, "expected": [4.1234e-6] * 5, "cycles": 10,
               "targets": [[0.412345, -0.123456, 0.512345]] * 5, "edge": 0.3, "centre": [0.4, -0.1, 0.5],
               "result": "sessions/demo-20261125-210830.result.yaml", "missing_steps": 0,
               "verdict": {"status": "pass", "message": "AP after 0.0185 mm, within its expected 0.012 ± 0.004 mm"}}
    header = {"config": {"verification": {"result_verdict": "pass", "notes": []}}, "robot": {"model": "ur5e"}}
    with Session.open(session_path) as session:
        _fits(verification_html(summary, header, "sessions/demo-20261125-210830-verify.session", session), tmp_path)


@pytest.mark.slow
def test_the_trend_page(tmp_path):
    robot, _, first = _identified("ur5e")
    models = [CalibratedModel.from_identification(i) for i in (first, _identified("ur5e", seed=8)[2])]
    result = compare(models, ["demo-20261125-210830", "demo-20261126-090000"], robot.limits, poses=100)
    _fits(compare_html(result, models, [1.7e9, 1.7e9 + 86400]), tmp_path)
