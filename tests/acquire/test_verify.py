"""Verification (``acquire verify``): ISO 9283 geometry and statistics, and whole runs on the simulated rig whose
truth differs from the nominal model: "before" AP is what the truth implies for the nominal commands, "after" AP
what it implies for the compensated ones (the identification's own error), within the noise of the barycentre.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.stats import chi2

from acquire.commands.cli import main as acquire
from acquire.running.session import Session
from acquire.verification.verify import APPROACH_AXES, REGISTER_POSES
from config.robots import load_robot
from drivers.sim.rig import SimulatedRig
from identify.applications.iso9283 import ISO_ORDER, accuracy, cube_poses, pose_result, visit_order
from identify.commands.cli import main as identify_main
from identify.io.result_io import result_to_dict
from identify.results.pipeline import identify
from identify.simulators.simulate import simulate
from kinematics.dh import points_from_joints

NOISE, SAMPLES, CYCLES = 5e-5, 5, 5
STEPS = REGISTER_POSES + 2 * 5 * CYCLES * 2 * len(APPROACH_AXES)  # each visit of a pose after its approach pose
ROBOT = load_robot("ur5e")


def test_cube_poses_and_visit_order() -> None:
    """P1 the centre; P2..P5 on the cube's space diagonals, 10 % of the diagonal from the corners of one diagonal
    plane; cycles visit P1, P5, P4, P3, P2."""
    centre, edge = np.array([0.4, -0.1, 0.3]), 0.2
    p = cube_poses(centre, edge)
    np.testing.assert_allclose(p[0], centre)
    diagonal = edge * np.sqrt(3)
    corners = centre + edge / 2 * np.array([[-1, -1, -1], [-1, 1, -1], [1, 1, 1], [1, -1, 1]])
    np.testing.assert_allclose(np.linalg.norm(p[1:] - corners, axis=1), 0.1 * diagonal)
    np.testing.assert_allclose(np.linalg.norm(p[1:] - centre, axis=1), 0.4 * diagonal)
    normal = np.cross(p[2] - p[1], p[4] - p[1])
    np.testing.assert_allclose((p - p[1]) @ normal, 0.0, atol=1e-15)  # one plane, through the centre
    assert visit_order(2) == [(1, 1), (1, 5), (1, 4), (1, 3), (1, 2), (2, 1), (2, 5), (2, 4), (2, 3), (2, 2)]
    assert ISO_ORDER == (1, 5, 4, 3, 2)


def test_ap_and_rp_follow_iso_9283() -> None:
    rng = np.random.default_rng(0)
    commanded = np.array([0.5, 0.0, 0.2])
    attained = commanded + np.array([1e-4, -2e-4, 5e-5]) + rng.normal(0, 3e-5, (30, 3))
    r = pose_result(3, commanded, attained)
    bary = attained.mean(axis=0)
    lengths = np.linalg.norm(attained - bary, axis=1)
    assert r.ap == pytest.approx(np.linalg.norm(bary - commanded), rel=1e-12)
    assert r.rp == pytest.approx(lengths.mean() + 3 * np.sqrt(np.sum((lengths - lengths.mean()) ** 2) / 29), rel=1e-12)
    assert r.ap_std == pytest.approx(3e-5 / np.sqrt(30), rel=0.4)  # the barycentre's spread along the offset
    acc = accuracy("x", np.tile(commanded, (5, 1)), {3: attained, 1: attained[:1]})  # one visit: no statistics
    assert [p.pose for p in acc.poses] == [3]
    with pytest.raises(ValueError, match="at least 2"):
        pose_result(1, commanded, attained[:1])


def _result(truth, tmp_path: Path, seed: int = 4) -> Path:
    """A calibration of ``truth`` (simulated sweeps and free poses, identified against the nominal)."""
    rng = np.random.default_rng(seed)
    meas, _ = simulate(truth, ROBOT.home, ROBOT.limits, rng, noise=NOISE, free_poses=20, check_poses=10)
    path = tmp_path / "cal.result.yaml"
    path.write_text(yaml.safe_dump(result_to_dict(identify(meas, ROBOT.nominal), ROBOT.nominal, "ur5e")))
    return path


def _truth_implied(path: Path, truth) -> tuple[dict, dict]:
    """Per mode, the AP each pose has on the truth for the commands the session recorded, and the measured one."""
    with Session.open(path) as session:
        info = session.header["config"]["verification"]
    base = np.array(info["base"])
    targets = np.array(info["targets"])
    implied = {}
    for mode in ("before", "after"):
        reached = points_from_joints(truth, np.array(info["q"][mode]))
        in_base = (reached - base[:3, 3]) @ base[:3, :3]
        implied[mode] = np.linalg.norm(in_base - targets, axis=1)
    summary = yaml.safe_load(path.with_suffix(".verify.yaml").read_text())
    measured = {m: np.array([p["ap"] for p in summary["runs"][m]["poses"]]) for m in ("before", "after")}
    return implied, measured


def _tolerance(noise: float, visits: int) -> float:
    """|AP measured - AP implied| is at most the barycentre's noise (3D, chi-square 1e-4) plus the arm's
    repeatability (2 µrad on joints about a metre from the TP)."""
    return float(np.sqrt(chi2.ppf(1 - 1e-4, 3))) * noise / np.sqrt(visits) + 5e-6


def test_verification_on_the_mock_rig_matches_its_truth_and_resumes(tmp_path, capsys) -> None:
    truth = SimulatedRig("ur5e", seed=0).truth  # the world of mock:ur5e
    result = _result(truth, tmp_path)
    session = tmp_path / "v.session"
    args = ["verify", "--result", str(result), "--robot", "mock:ur5e?fault=protective_stop@23", "--tracker", "mock",
            "--session", str(session), "--cycles", str(CYCLES), "--quiet"]
    assert acquire(args) == 1  # a protective stop mid-run: the session keeps what was measured
    err = capsys.readouterr().err
    assert "acquire verify --resume" in err
    with Session.open(session) as s:
        done = {r.plan_index: r for r in s.steps()}
        assert 0 < len(done) < STEPS
    assert acquire(["verify", "--resume", str(session), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "verdict: pass" in out
    with Session.open(session) as s:
        steps = s.steps()
        assert [r.plan_index for r in steps] == list(range(STEPS))  # none lost, none twice
        assert all(steps[i] == r for i, r in done.items())
    implied, measured = _truth_implied(session, truth)
    tol = _tolerance(NOISE, CYCLES * SAMPLES)
    np.testing.assert_allclose(measured["before"], implied["before"], atol=tol)
    np.testing.assert_allclose(measured["after"], implied["after"], atol=tol)
    assert implied["before"].min() > 0.5e-3  # the truth is millimetres from the nominal model
    assert measured["after"].max() < 2 * NOISE  # compensated: within twice the tracker noise
    report = session.with_suffix(".report.html").read_text()
    assert 'id="headline"' in report and "AP, pose accuracy" in report and "Verdict: PASS" in report
    assert "domain: all 5 poses lie inside" in report and "domain: all 5 poses lie inside" in " ".join(out.split())
    assert yaml.safe_load(session.with_suffix(".verify.yaml").read_text())["domain"]["poses_outside"] == 0
    # a verification session is neither identified nor resumed as an acquisition
    assert acquire(["--resume", str(session)]) == 2
    assert "acquire verify --resume" in capsys.readouterr().err
    assert identify_main([str(session)]) == 2
    assert "verification session" in capsys.readouterr().err
    # a complete session: nothing moves, the results are written again
    assert acquire(["verify", "--resume", str(session), "--quiet"]) == 0
    assert "is complete" in capsys.readouterr().out


def test_verification_refusals_and_dry_run(tmp_path, capsys) -> None:
    truth = SimulatedRig("ur5e", seed=0).truth
    result = _result(truth, tmp_path, seed=5)
    assert acquire(["verify", "--result", str(result), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "test cube" in out and "P5" in out and "dry run: nothing was connected or moved" in out
    assert "domain: all 5 poses lie inside" in out  # full sweeps: the test poses are within the fitted ranges
    narrow = yaml.safe_load(result.read_text())  # the same result fitted, say, on q1 in [-0.1, 0.1] rad only
    narrow["domain"]["joints"][0] = [-0.1, 0.1]
    (tmp_path / "narrow.yaml").write_text(yaml.safe_dump(narrow))
    assert acquire(["verify", "--result", str(tmp_path / "narrow.yaml"), "--dry-run"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "of 5 poses lie outside the result's fitted joint ranges" in out and "farthest: joint 1 by" in out
    assert "a lower bound" in out
    far = tmp_path / "far.yaml"
    far.write_text("schema: 1\nverify: {cube_centre: [3.0, 0.0, 0.5], cube_edge: 0.2}\n")
    assert acquire(["verify", "--result", str(result), "--config", str(far), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert "test refused" in err and "unreachable" in err and len(err.strip().splitlines()) == 1
    low = tmp_path / "low.yaml"  # a cube through the table: every move is checked against the cell
    low.write_text("schema: 1\nverify: {cube_centre: [-0.45, -0.1, 0.05], cube_edge: 0.1}\n")
    assert acquire(["verify", "--result", str(result), "--config", str(low), "--dry-run"]) == 2
    assert "mounting surface" in capsys.readouterr().err
    assert acquire(["verify", "--result", str(result), "--robot", "mock:ur10e", "--dry-run"]) == 2
    assert "is a calibration of ur5e" in capsys.readouterr().err
    assert acquire(["verify", "--result", str(tmp_path / "none.yaml")]) == 2
    assert "no such result file" in capsys.readouterr().err
    failing = yaml.safe_load(result.read_text())
    failing["verdict"]["status"] = "fail"
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(failing))
    assert acquire(["verify", "--result", str(tmp_path / "bad.yaml")]) == 2
    assert "fails its verdict" in capsys.readouterr().err
    assert acquire(["verify", "--result", str(result), "--cycles", "1", "--dry-run"]) == 2
    (tmp_path / "v.session").write_text("taken")
    assert acquire(["verify", "--result", str(result), "--session", str(tmp_path / "v.session")]) == 2
    assert "already exists" in capsys.readouterr().err


def test_verification_against_the_ur_controller_emulator(tmp_path, capsys) -> None:
    """The real command, the real ur_rtde client and the real serial tracker driver against the UR controller
    emulator and its simulated tracker: the same agreement with the emulated truth as on the mock rig."""
    pytest.importorskip("rtde_control", reason="ur_rtde is not installed (pip install 'ur-rtde==1.6.5', the ur extra)")
    from tests.ur_emulator import EmulatorProcess, ScaledClock

    noise, samples, cycles = 2e-5, 3, 3
    rig = SimulatedRig("ur5e", clock=ScaledClock(100.0), ring=1e-5, ring_tau=0.05)
    site = tmp_path / "site.yaml"
    site.write_text(f"schema: 1\ntracker: {{noise: {noise:.1e}}}\nplan: {{settle_time: 0.02, samples_per_step: "
                    f"{samples}}}\nverify: {{cycles: {cycles}}}\ntimeouts: {{connect: 10.0, move: 30.0, settle: 10.0, "
                    "measure: 5.0}\n")
    with EmulatorProcess(rig=rig) as emu:
        tracker = emu.serve_tracker("polled-xyz", noise, 1)
        truth = emu.truth()
        result = _result(truth, tmp_path, seed=6)
        session = tmp_path / "ur.session"
        code = acquire(["verify", "--result", str(result), "--robot", f"ur5e@{emu.host}", "--tracker",
                        f"serial:{tracker}?protocol=polled-xyz", "--yes", "--config", str(site), "--session",
                        str(session), "--quiet"])
        out, err = capsys.readouterr()
        assert code == 0, err + out
    implied, measured = _truth_implied(session, truth)
    # the emulated encoders round the commanded joints (about 1e-7 rad, well under a micrometre at the TP)
    tol = _tolerance(noise, cycles * samples) + 2e-6
    np.testing.assert_allclose(measured["before"], implied["before"], atol=tol)
    np.testing.assert_allclose(measured["after"], implied["after"], atol=tol)
    assert implied["before"].min() > 0.5e-3 and measured["after"].max() < 2 * NOISE


@pytest.mark.slow
def test_identify_report_shows_a_verification_run(tmp_path, capsys) -> None:
    """identify --report with --verification puts the run's AP and RP in the headline; a file that is not a
    verification summary is refused in one line."""
    pytest.importorskip("matplotlib")
    from identify.io.csvio import format_measurements

    truth = SimulatedRig("ur5e", seed=0).truth
    meas, _ = simulate(truth, ROBOT.home, ROBOT.limits, np.random.default_rng(8), noise=NOISE, steps=12,
                       free_poses=8, check_poses=4)
    data = tmp_path / "m.csv"
    data.write_text(format_measurements(meas, {}))
    import hashlib

    def verified(name: str, source: Path) -> Path:  # a result of ``source`` and the summary of its verification
        result = tmp_path / f"{name}.result.yaml"
        result.write_text(yaml.safe_dump({"source": str(source)}))
        summary = {"verdict": {"status": "pass", "message": "every pose within what the result predicts"},
                   "cycles": 10, "result": str(result),
                   "result_sha256": hashlib.sha256(result.read_bytes()).hexdigest(),
                   "runs": {"before": {"ap_max": 1.5e-3, "rp_max": 8e-5}, "after": {"ap_max": 2e-5, "rp_max": 8e-5}}}
        out = tmp_path / f"{name}.verify.yaml"
        out.write_text(yaml.safe_dump(summary))
        return out

    verify_yaml = verified("v", data)
    report = tmp_path / "r.html"
    args = [str(data), "--robot", "ur5e", "--report", str(report)]
    assert identify_main([*args, "--verification", str(verify_yaml)]) == 0
    text = report.read_text()
    assert "AP, pose accuracy" in text and "1.5000 mm" in text and "every pose within what the result predicts" in text
    capsys.readouterr()
    # a verification of another calibration, or of a result file changed since, is refused before any computing
    other_data = tmp_path / "other.csv"
    other_data.write_text(data.read_text())
    for summary, says in ((verified("w", other_data), "w.result.yaml (a calibration of"), (verify_yaml, "has changed")):
        if summary == verify_yaml:
            (tmp_path / "v.result.yaml").write_text(yaml.safe_dump({"source": str(data), "edited": True}))
        assert identify_main([*args, "--force", "--verification", str(summary)]) == 2
        err = capsys.readouterr().err
        assert says in err and str(data) in err and len(err.strip().splitlines()) == 1
    assert identify_main([*args, "--force", "--verification", str(data)]) == 2
    assert "not the .verify.yaml" in capsys.readouterr().err
    assert identify_main([str(data), "--verification", str(verify_yaml)]) == 2
    assert "goes with --report" in capsys.readouterr().err


def coupled_run(folder: str) -> tuple[int, int, str]:
    """A FANUC whose controller reads J3 against the horizontal: a small mock acquisition (the result carries the
    coupling), then its verification; exit codes and the verification session's path."""
    import contextlib
    import io

    cal, ver = Path(folder) / "f.session", Path(folder) / "fv.session"
    with contextlib.redirect_stdout(io.StringIO()):
        code_a = acquire(["--robot", "mock:fanuc_lrmate200id", "--tracker", "mock", "--steps", "12", "--free-poses",
                          "10", "--session", str(cal), "--quiet"])
        code_v = acquire(["verify", "--result", str(cal.with_suffix(".result.yaml")), "--robot",
                          "mock:fanuc_lrmate200id", "--session", str(ver), "--cycles", "4", "--quiet"])
    return code_a, code_v, str(ver)


@pytest.mark.slow
def test_verification_of_a_coupled_robot_commands_its_readings(tmp_path) -> None:
    """The plan holds DH values; the coupled controller is commanded their readings (the session's coupling); the
    identified model, which takes readings, is solved and converted: AP agrees with the simulated truth."""
    code_a, code_v, path = coupled_run(str(tmp_path))
    assert (code_a, code_v) == (0, 0)
    with Session.open(path) as s:
        assert s.coupling is not None and not s.coupling.is_identity
        first = s.steps()[0]
        planned = s.plan.steps[first.plan_index].q
    # the step records the controller's readings (commanded and read); the plan holds DH values
    assert abs(planned[1]) > 0.01  # J2 off zero: readings and DH values differ
    np.testing.assert_allclose(s.coupling.dh_from_readings(np.array([first.q_act])), [planned], atol=1e-4)
    assert np.max(np.abs(np.array(first.q_cmd) - first.q_act)) < 1e-4
    implied, measured = _truth_implied(Path(path), SimulatedRig("fanuc_lrmate200id", seed=0).truth)
    tol = _tolerance(NOISE, 4 * SAMPLES)
    np.testing.assert_allclose(measured["before"], implied["before"], atol=tol)
    np.testing.assert_allclose(measured["after"], implied["after"], atol=tol)
    assert implied["before"].min() > 0.5e-3 and measured["after"].max() < 2 * NOISE


def _registration_allowance(noise: float, samples: int) -> float:
    """How far a rigid registration on REGISTER_POSES poses (each the mean of ``samples`` readings of per-axis
    ``noise``) can shift a point inside the cube: six parameters on 3·REGISTER_POSES values, taken at 4 sigma
    (3D) and doubled for the cube poses lying up to twice as far out as the registration poses."""
    return 2 * 4 * noise / np.sqrt(samples) * np.sqrt(6 / (3 * REGISTER_POSES)) * np.sqrt(3)


def test_a_moved_tracker_gives_the_same_figures_and_another_arm_fails(tmp_path, capsys) -> None:
    """The tracker put back elsewhere (turned 123°, shifted 2 m): the registration finds the move and AP agrees with
    the simulated truth as without it. Another arm of the same model at the same place: exit 3, named."""
    truth = SimulatedRig("ur5e", seed=0).truth
    result = _result(truth, tmp_path)
    session = tmp_path / "moved.session"
    shift, turn = np.array([1.5, -1.2, 0.6]) * 2.0 / np.linalg.norm([1.5, -1.2, 0.6]), np.array([40.0, -100.0, 60.0])
    tracker = f"mock?moved={','.join(map(str, shift))}&turned={','.join(map(str, turn))}"
    assert acquire(["verify", "--result", str(result), "--robot", "mock:ur5e", "--tracker", tracker, "--session",
                    str(session), "--cycles", str(CYCLES), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "verdict: pass" in out and "tracker registered on 8 poses" in out
    summary = yaml.safe_load(session.with_suffix(".verify.yaml").read_text())
    reg = summary["registration"]
    # the registration's rotation error (noise / ~0.2 m) moves the tracker's origin, 1-2 m away, by up to ~1 mm
    assert reg["moved"] == pytest.approx(2.0, abs=1e-3)
    assert reg["turned_deg"] == pytest.approx(np.linalg.norm(turn), abs=0.05)
    implied, measured = _truth_implied(session, truth)  # the truth without the move: AP is the base frame's
    tol = _tolerance(NOISE, CYCLES * SAMPLES) + _registration_allowance(NOISE, SAMPLES)
    np.testing.assert_allclose(measured["before"], implied["before"], atol=tol)
    np.testing.assert_allclose(measured["after"], implied["after"], atol=tol)
    assert implied["before"].min() > 0.5e-3
    # distance accuracy P2-P4 (ISO 9283 7.3) against the truth's: a rigid registration leaves distances alone, so
    # only the noise of D̄ counts: sqrt(2) x the visit's noise over sqrt(cycles), at 4 sigma, plus repeatability
    with Session.open(session) as s:
        info = s.header["config"]["verification"]
    targets = np.array(info["targets"])
    for mode in ("before", "after"):
        reached = points_from_joints(truth, np.array(info["q"][mode]))
        ad_true = np.linalg.norm(reached[1] - reached[3]) - np.linalg.norm(targets[1] - targets[3])
        run = summary["runs"][mode]
        assert run["distance"]["ad"] == pytest.approx(ad_true, abs=4 * np.sqrt(2 / CYCLES / SAMPLES) * NOISE + 5e-6)
        assert run["distance"]["n"] == CYCLES and run["drift"]["visits_each"] == 2
    assert abs(summary["runs"]["before"]["distance"]["ad"]) > 0.2e-3  # the nominal model's distances are off
    assert "AD P2-P4 (7.3)" in out
    other = tmp_path / "other.session"
    assert acquire(["verify", "--result", str(result), "--robot", "mock:ur5e?arm=7", "--tracker", "mock",
                    "--session", str(other), "--cycles", "2", "--quiet"]) == 3
    out = capsys.readouterr().out
    assert "verdict: fail" in out and "another arm or another tool" in out


def test_distance_drift_and_multi_directional_follow_iso_9283_by_hand() -> None:
    """ISO 9283 7.3, 7.6 and 7.2 on numbers worked out by hand (mm written as 1e-3 m)."""
    from identify.applications.iso9283 import distance_result, drift, multi_directional

    mm = 1e-3
    a = np.zeros((3, 3))
    b = np.array([[1.001, 0, 0], [1.002, 0, 0], [1.003, 0, 0]])  # D_j = 1.001, 1.002, 1.003 m
    d = distance_result(2, 4, [0, 0, 0], [1, 0, 0], a, b)
    assert d.commanded == 1.0 and d.mean == pytest.approx(1.002, abs=1e-15)
    assert d.ad == pytest.approx(2 * mm, abs=1e-15)  # D̄ - D_c
    assert d.rd == pytest.approx(3 * mm, rel=1e-9)  # 3 S_D, S_D = 1 mm
    assert d.ad_std == pytest.approx(mm / np.sqrt(3), rel=1e-9) and d.rd_std == pytest.approx(1.5 * mm, rel=1e-9)
    # P1 at the origin: first third (2 visits) at (1, 0, 0) mm, last third at (0, 2, 0) and (0, 2, 0.002) mm
    visits = np.array([[1, 0, 0], [1, 0, 0], [5, 5, 5], [5, 5, 5], [0, 2, 0], [0, 2, 0.002]]) * mm
    dr = drift(1, np.zeros(3), visits)
    assert dr.first.ap == pytest.approx(mm) and dr.first.rp == pytest.approx(0.0, abs=1e-15)
    assert dr.last.ap == pytest.approx(np.hypot(2, 0.001) * mm, rel=1e-12)
    assert dr.dap == pytest.approx((np.hypot(2, 0.001) - 1) * mm, rel=1e-12)
    assert dr.drp == pytest.approx(0.001 * mm, rel=1e-9)  # l_j = 0.001 mm both: l̄ = 0.001 mm, S_l = 0
    # barycentres from three directions: pairwise 5, 1 and sqrt(26) mm
    assert multi_directional(np.array([[0, 0, 0], [3, 4, 0], [0, 0, 1]]) * mm) == pytest.approx(np.sqrt(26) * mm)
    with pytest.raises(ValueError, match="at least 4 visits"):
        drift(1, np.zeros(3), visits[:3])
    with pytest.raises(ValueError, match="same 2 or more cycles"):
        distance_result(2, 4, [0, 0, 0], [1, 0, 0], a, b[:2])


def test_registration_variance_is_that_of_a_mean_at_the_centroid_and_grows_outside() -> None:
    """At the centroid of the fitted points the rotation does not count: the 3D variance is expected² / k (a mean of
    k points); beyond them it grows with the distance (the rotation's lever arm)."""
    from acquire.verification.verify_analysis import registration_variance

    corners = 0.1 * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    var = registration_variance(corners + 5.0, np.array([[5.0, 5.0, 5.0], [5.3, 5.0, 5.0]]), 1e-4)
    assert var[0] == pytest.approx(1e-8 / 8, rel=1e-9)
    # 0.3 m out along x: the rotations about y and z (variance sigma² / (8 · 0.02 m²) each) add 2 · 0.09 m² of it
    assert var[1] == pytest.approx(1e-8 / 8 + 2 * 0.09 * (1e-8 / 3) / (8 * 0.02), rel=1e-9)


def test_before_is_what_the_controller_runs_today(tmp_path, capsys) -> None:
    """Issue 24, item 4: "before" was always the nominal model; a result that records the controller's own
    calibration (a UR's factory DH values) is commanded "before" with that, and the dry run names it."""
    truth = SimulatedRig("ur5e", seed=0).truth
    result = _result(truth, tmp_path, seed=5)
    assert acquire(["verify", "--result", str(result), "--dry-run"]) == 0
    nominal_run = capsys.readouterr().out
    assert "before (nominal ur5e)" in nominal_run
    doc = yaml.safe_load(result.read_text())
    table = ROBOT.nominal.dh_table()
    dh = {key: table[:, k].tolist() for k, key in enumerate(("theta", "d", "a", "alpha"))}
    dh["theta"][1] += 0.01  # a factory calibration 10 mrad off the nominal on joint 2
    doc["controller"] = {"model": "factory calibration", "dh": dh}
    factory = tmp_path / "factory.result.yaml"
    factory.write_text(yaml.safe_dump(doc))
    assert acquire(["verify", "--result", str(factory), "--dry-run"]) == 0
    factory_run = capsys.readouterr().out
    assert "before (factory calibration of the ur5e's controller)" in factory_run

    def before_joints(text: str) -> list[str]:
        return [line for line in text.splitlines() if line.lstrip().startswith(("P1", "P2", "P3", "P4", "P5"))]

    assert before_joints(factory_run) != before_joints(nominal_run)
