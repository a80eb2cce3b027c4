"""The HTML report: renders for simulated identifications, holds every section and one embedded image per
figure, needs nothing from outside the file, and loads in headless Chromium (when installed) with every
image decoded and no script error."""

from __future__ import annotations

import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from acquire.running.session import Session
from config.robots import load_robot
from identify.report.html import report_html, write_report
from identify.results.pipeline import identify
from identify.simulators.simulate import simulate
from kinematics.truth import random_truth
from tests._session_writer import CONFIG, ROBOT, TRACKER, record_for, small_plan

CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None)
SECTIONS = ("dh-table", "joints", "frames-3d", "validation", "domain", "sweeps")


class _Collector(HTMLParser):
    """Counts figures and images and collects every URL-bearing attribute."""

    def __init__(self) -> None:
        super().__init__()
        self.figures = 0
        self.images: list[str] = []
        self.urls: list[str] = []
        self.ids: list[str] = []

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "figure":
            self.figures += 1
        if tag == "img":
            self.images.append(attrs.get("src", ""))
        self.urls += [v for k, v in attrs.items() if k in ("src", "href") and v]
        if "id" in attrs:
            self.ids.append(attrs["id"])


def _identified(name: str, seed: int = 7, check_poses: int = 8, outliers: int = 2):
    robot = load_robot(name)
    rng = np.random.default_rng(seed)
    truth = random_truth(robot.nominal, robot.home, rng)
    meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=5e-5, steps=12, free_poses=6,
                       check_poses=check_poses, outliers=outliers)
    return robot, meas, identify(meas, robot.nominal)


@pytest.fixture(scope="module")
def session_path(tmp_path_factory):
    """A session with an aborted run, a resume, an event, missing steps and rejected readings."""
    path = tmp_path_factory.mktemp("session") / "run.session"
    plan = small_plan()
    with Session.create(path, plan, CONFIG, ROBOT, TRACKER) as session:
        session.begin_run()
        for i in range(15):
            session.record_step(record_for(plan, i))
        session.event("pause", "operator paused <to check the target>")
        session.end_run("aborted", "stopped by the operator")
        session.begin_run()
        while (i := session.next_index()) is not None:
            session.record_step(record_for(plan, i))
        session.end_run("complete")
    return path


@pytest.fixture(scope="module")
def recorded_report(session_path) -> tuple[int, str]:
    """The ur5e report with the acquisition record of ``session_path`` (read by two tests): joints, HTML."""
    robot, meas, ident = _identified("ur5e")
    with Session.open(session_path) as session:
        return robot.n_joints, report_html(ident, meas, robot.nominal, robot.name, session=session, title="cell <7>")


def _parse(text: str) -> _Collector:
    collector = _Collector()
    collector.feed(text)
    return collector


@pytest.mark.slow
@pytest.mark.parametrize("name", ["ur5e", "track_ur5e", "scara"])
def test_report_renders_with_sections_and_one_image_per_figure(name):
    robot, meas, ident = _identified(name)
    text = report_html(ident, meas, robot.nominal, robot.name, source="simulated")
    parsed = _parse(text)
    assert set(SECTIONS) <= set(parsed.ids)
    assert "acquisition" not in parsed.ids
    # one figure per joint, the 3D view, validation, sweeps
    assert parsed.figures == robot.n_joints + 3
    assert len(parsed.images) == parsed.figures
    assert all(src.startswith("data:image/png;base64,") for src in parsed.images)
    assert all(url.startswith("data:") for url in parsed.urls)  # self-contained: nothing to fetch
    assert f"vs {robot.name}" in text and "±" in text
    for s in ident.sweeps:
        assert f"<td>{s.sweep}</td>" in text
    # the domain: the fitted rows' joint ranges, and how many held-out poses lie beyond them
    fit = ~meas.check
    fit[np.array(ident.rejected_rows, dtype=int) - 1] = False
    low, high = meas.q[fit].min(axis=0), meas.q[fit].max(axis=0)
    beyond = int(np.sum(np.any((meas.q[meas.check] < low - 1e-9) | (meas.q[meas.check] > high + 1e-9), axis=1)))
    held = int(meas.check.sum())
    assert (f"all {held} poses lie inside" if beyond == 0 else f"{beyond} of {held} poses lie outside") in text
    assert (f"<td>{np.degrees(high[0] - low[0]):.1f}°</td>" if robot.nominal.joint_types[0] == "R"
            else f"<td>{(high[0] - low[0]) * 1e3:.1f} mm</td>") in text


@pytest.mark.slow
def test_report_without_holdout_or_nominal_and_with_reference():
    robot, meas, ident = _identified("ur5e", check_poses=0, outliers=0)
    assert ident.validation is None
    text = report_html(ident, meas, reference=("factory calibration", robot.nominal))
    parsed = _parse(text)
    assert "No held-out poses" in text
    assert "vs factory calibration" in text
    assert parsed.figures == robot.n_joints + 2 == len(parsed.images)


def test_report_rejects_measurements_it_was_not_made_from():
    _, meas, ident = _identified("scara")
    with pytest.raises(ValueError, match="fitted rows"):
        report_html(ident, meas.subset(np.arange(len(meas)) > 3))


@pytest.mark.slow
def test_report_with_acquisition_record(recorded_report, tmp_path):
    joints, text = recorded_report
    parsed = _parse(text)
    assert "acquisition" in parsed.ids
    assert parsed.figures == joints + 4 == len(parsed.images)  # + drift over time
    for expected in ("test-tracker", "T-9", "rate: 100 Hz", "aborted", "stopped by the operator", "complete",
                     "no valid reading", "operator paused &lt;to check the target&gt;", "cell &lt;7&gt;"):
        assert expected in text
    assert re.search(r"\d+ tracker readings, \d+ rejected", text)
    path = tmp_path / "report.html"
    write_report(path, text)
    assert path.read_text(encoding="utf-8") == text


_PROBE = """<script>
window.probeErrors = 0;
window.addEventListener('error', function () { window.probeErrors++; }, true);
window.addEventListener('load', function () {
  var imgs = document.images, broken = 0;
  for (var i = 0; i < imgs.length; i++) { if (!imgs[i].complete || imgs[i].naturalWidth === 0) broken++; }
  var p = document.createElement('p'); p.id = 'probe';
  p.textContent = 'images=' + imgs.length + ' broken=' + broken + ' errors=' + window.probeErrors;
  document.body.appendChild(p);
});
</script>"""


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed")
def test_report_loads_in_headless_chromium(recorded_report, tmp_path):
    _, text = recorded_report
    figures = _parse(text).figures
    path = tmp_path / "probe.html"
    path.write_text(text.replace("<body>", "<body>" + _PROBE, 1), encoding="utf-8")
    done = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                           "--dump-dom", path.as_uri()], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    probe = re.search(r'<p id="probe">([^<]*)</p>', done.stdout)
    assert probe is not None, done.stdout[-2000:]
    assert probe.group(1) == f"images={figures} broken=0 errors=0"
    for section in (*SECTIONS, "acquisition"):
        assert f'id="{section}"' in done.stdout


@pytest.mark.slow
def test_report_3d_view_shows_the_mounting_surface_and_the_swept_envelope():
    """With a cell view (acquire passes the plan's), the 3D view draws the surface and the envelope; the view is in
    the robot's base frame (DH frame 0), where the cell is given, so the arm stands upright."""
    from identify.report.figures import figure_frames

    robot, meas, ident = _identified("ur5e")
    envelope = np.array([[0.3, 0.1, 0.4], [-0.2, 0.4, 0.6], [0.1, -0.3, 0.2]])
    cell = {"normal": np.array([0.0, 0.0, 1.0]), "offset": 0.0, "envelope": envelope}
    text = report_html(ident, meas, robot.nominal, robot.name, cell=cell)
    assert "the mounting surface (green) and the space the plan swept the arm through" in text
    fit = meas.subset(~meas.check)
    ax = figure_frames(ident, fit, cell).axes[0]
    drawn = next(c for c in ax.collections if c.get_label() == "swept by the plan")
    x, y, z = drawn._offsets3d  # the envelope in the base frame, mm
    np.testing.assert_allclose(np.column_stack([x, y, z]), envelope * 1e3, atol=1e-9)
    # and the measured points there too: the tracker's frame mapped through the inverse of the identified base
    measured = next(c for c in ax.collections if c.get_label() == "measured TP")
    base = ident.model.base
    np.testing.assert_allclose(np.column_stack(measured._offsets3d),
                               (fit.points - base[:3, 3]) @ base[:3, :3] * 1e3, atol=1e-6)
    assert any(type(c).__name__ == "Poly3DCollection" for c in ax.collections)  # the surface patch


@pytest.mark.slow
def test_report_headline_says_the_verdict_and_the_accuracy_before_and_after(tmp_path):
    """The first section: the verdict, then the TP error of the nominal model (placed on the identified one) and
    of the identified model at the held-out poses, predicted and measured, each with its uncertainty; with a
    verification summary, AP and RP before and after."""
    from identify.report.headline import accuracy_summary

    robot, meas, ident = _identified("ur5e", outliers=0)
    summary = accuracy_summary(ident, meas, robot.nominal, robot.name)
    before, after = summary["before"], summary["after"]
    assert summary["poses"] == 8
    assert after["measured"] == pytest.approx(ident.validation.rms, rel=1e-12)
    # the truth is a perturbed nominal (0.5 mm, 1 mrad): the nominal misses by millimetres, the identified model
    # by what the noise explains; the prediction of the nominal's miss agrees with the measurement
    assert before["measured"] > 10 * after["measured"]
    assert abs(before["predicted"] - before["measured"]) < 3 * np.hypot(before["measured_std"], after["measured"])
    verification = {"verdict": {"status": "pass", "message": "AP before 1.6 mm, after 0.02 mm"}, "cycles": 10,
                    "runs": {"before": {"ap_max": 1.6e-3, "rp_max": 9e-5}, "after": {"ap_max": 2.3e-5, "rp_max": 9e-5}},
                    "predicted": {"before": [1.61e-3] * 5, "after": [0.0] * 5}, "expected": [7e-6] * 5}
    text = report_html(ident, meas, robot.nominal, robot.name, verification=verification)
    parsed = _parse(text)
    assert parsed.ids[0] == "headline"
    head = text[text.index('id="headline"'):text.index("</section>")]
    assert f"Verdict: {ident.verdict.status.upper()}" in head and "before (nominal ur5e)" in head
    assert f"after (identified, {ident.use} model)" in head
    assert f"{before['measured'] * 1e3:.4f} ± {before['measured_std'] * 1e3:.4f} mm" in head
    assert "AP, pose accuracy" in head and "1.6000 mm" in head and "0.0230 mm" in head
    assert "Verification (pass)" in head


@pytest.mark.slow
def test_notes_sit_under_a_neutral_heading_and_the_title_names_the_robot():
    """Before, "joint errors selected: none" and the reduced chi-square sat under an orange "Warnings" heading below
    a PASS, and the title named only the joint types."""
    robot, meas, ident = _identified("ur5e")
    text = report_html(ident, meas, robot.nominal, robot.name)
    notes = re.search(r'<section id="notes"><h2>Notes</h2>(.*?)</section>', text, re.S)
    assert notes is not None and "<li>" in notes.group(1) and 'class="warn"' not in notes.group(1)
    assert "Warnings" not in text
    assert "<title>DH identification report: ur5e (RRRRRR)</title>" in text
