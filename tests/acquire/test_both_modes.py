"""Sessions that hold both kinds of rows (``acquire --mode both``): the plan, the dry run of the three modes, a mixed
session end to end (export, identification against the simulated truth, the clock), checking the streams' timing
with the stop-and-go rows (``identify --rows``), and resume (real CLI runs, real SQLite files)."""

from __future__ import annotations

import shutil
import sqlite3
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.stats import chi2

from acquire.commands.cli import main
from acquire.planning.plan import build_plan, check_plan, plan_clearance
from acquire.planning.plan_continuous import build_continuous_plan, validation_poses
from acquire.planning.plan_modes import build_both_plan, build_mode_plan, mode_site, plan_mode
from acquire.running.session import Session
from acquire.running.stream_loop import StreamingUnsupported, check_streams
from config.robots import load_robot
from config.site import SiteConfig
from drivers.sim.rig import SimulatedRig
from drivers.sim.stream import robot_time_of_stamps
from identify.commands.cli import main as identify_main
from identify.io.csvio import format_measurements, read_measurements
from identify.io.result_io import load_result, validation_of
from identify.simulators.simulate import random_poses
from kinematics.dh import points_from_joints
from session.plan import Plan

UR5E = load_robot("ur5e")
ROBOT = "mock:ur5e"
#: 12 ms latency, -0.08 % drift, 20 µs stamp jitter; the noise seed differs from the robot's
TRACKER = "mock?latency=0.012&drift=-0.0008&stamp_jitter=2e-5&seed=5"
SITE = "schema: 1\nplan:\n  steps_per_sweep: 12\n  check_poses: 6\n"
FALSE_ALARM = 1e-3  # per test: the chance that a correct result fails a noise-derived bound below


def _one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, lines
    return lines[0]


# --- the plan ------------------------------------------------------------------------------------------------


def test_the_plan_of_both_holds_every_stop_and_go_sweep_and_every_stream() -> None:
    site = mode_site(SiteConfig.default(), "both", None)
    both, step, cont = build_both_plan(UR5E, site), build_plan(UR5E, site), build_continuous_plan(UR5E, site)
    assert (plan_mode(both), plan_mode(step), plan_mode(cont)) == ("both", "step", "continuous")
    assert build_mode_plan("both", UR5E, site) == both and build_mode_plan(None, UR5E, site) == step
    assert check_plan(both, UR5E) == []
    clearance = plan_clearance(both, UR5E, site)
    assert clearance is not None and clearance.slack >= clearance.guard  # every move, the streamed ones too
    assert Plan.from_json(both.to_json()) == both

    def sweeps(plan: Plan) -> list[tuple[int, tuple[float, ...]]]:
        return [(s.joint, s.q) for s in plan.steps if s.kind == "sweep"]

    def streams(plan: Plan) -> list[tuple]:
        return [(s.joint, s.start, s.q, s.speed, s.acceleration) for s in plan.steps if s.kind == "stream"]

    assert sweeps(both) == sweeps(step) and len(sweeps(both)) == 6 * 36
    assert sorted(streams(both)) == sorted(streams(cont)) and [s[0] for s in streams(both)] == [6, 5, 4, 3, 2, 1]
    checks = [s.q for s in both.steps if s.role == "check"]
    assert checks == [s.q for s in cont.steps if s.role == "check"] and len(checks) == validation_poses()
    assert not any(s.kind == "free" and s.role == "fit" and s.joint for s in both.steps)
    # per joint: its stop-and-go sweep, the range start, its stream, home; a stop-and-go sweep shares one id
    kinds = [s.kind for s in both.steps]
    for s in both.steps:
        if s.kind == "stream":
            assert kinds[s.index - 1] == "free" and both.steps[s.index - 1].q == s.start
            assert kinds[s.index - 2] == "sweep" and both.steps[s.index - 2].joint == s.joint
            assert kinds[s.index + 1] == "home"
    ids: dict[int, set[tuple[str, int]]] = {}
    for s in both.steps:
        if s.kind != "home":
            ids.setdefault(s.sweep, set()).add((s.kind, s.joint))
    assert all(len(v) == 1 for v in ids.values())
    assert sum(1 for v in ids.values() if next(iter(v))[0] == "sweep") == 6


def _modes(out: str) -> dict[str, tuple[int, float]]:
    """The dry run's mode table: mode -> (robot time s, predicted accuracy mm)."""
    rows = {}
    for line in out.splitlines():
        words = line.split()
        if len(words) >= 6 and words[0] in ("step", "continuous", "both") and words[-1] == "mm":
            h, m, s = (int(v) for v in words[1].split(":"))
            rows[words[0]] = (3600 * h + 60 * m + s, float(words[-2]))
    return rows


@pytest.mark.slow
def test_dry_run_compares_the_three_modes(capsys) -> None:
    tables = {}
    for mode in ("step", "continuous", "both"):
        assert main(["--robot", "ur5e", "--tracker", "mock", "--dry-run", "--mode", mode]) == 0
        out = capsys.readouterr().out
        assert "modes (--mode step | continuous | both)" in out
        tables[mode] = _modes(out)
        estimated = next(line for line in out.splitlines() if line.startswith("estimated duration:")).split()[-1]
        h, m, s = (int(v) for v in estimated.split(":"))
        assert abs(3600 * h + 60 * m + s - tables[mode][mode][0]) <= 1  # the plan shown is its mode's row
    # each mode's row is its own default plan, whichever mode is shown
    assert tables["step"] == tables["continuous"] == tables["both"]
    rows = tables["both"]
    assert set(rows) == {"step", "continuous", "both"}
    (t_step, a_step), (t_cont, a_cont), (t_both, a_both) = rows["step"], rows["continuous"], rows["both"]
    assert t_cont < 0.3 * t_step and t_cont < t_both
    # both holds the continuous plan's data and more: its bound can only be lower; the streams beat the steps
    assert a_both <= a_cont + 1e-4 and a_cont < a_step


def test_a_plan_that_streams_is_refused_before_anything_moves_with_a_tracker_that_cannot() -> None:
    from drivers.registry import open_tracker
    from drivers.sim.robot import open_robot
    from drivers.sim.tracker import open_tracker as open_sim_tracker

    rig = SimulatedRig.from_spec(ROBOT, "mock")
    robot, sim_tracker = open_robot(ROBOT, rig=rig), open_sim_tracker("mock", rig=rig)
    robot.connect(1.0)
    sim_tracker.connect(1.0)
    site = mode_site(SiteConfig.default(), "both", None)
    both, step = build_both_plan(UR5E, site), build_plan(UR5E, site)
    polled = open_tracker("serial:loop://?protocol=polled-xyz")  # answers when asked: no device timestamps
    moves = rig.moves
    with pytest.raises(StreamingUnsupported, match=r"cannot stream with device timestamps.*use --mode step"):
        check_streams(robot, polled, both, 1.0, 250.0)
    with pytest.raises(StreamingUnsupported, match="object does not"):
        check_streams(robot, object(), both, 1.0, 250.0)
    check_streams(robot, polled, step, 1.0, 250.0)  # a stop-and-go plan needs no stream
    check_streams(robot, sim_tracker, both, 1.0, 250.0)  # the simulated devices stream
    assert rig.moves == moves and not rig._moving  # nothing moved


# --- a mixed session end to end ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def mixed(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("mixed")
    (folder / "site.yaml").write_text(SITE)
    path = folder / "m.session"
    code = main(["--robot", ROBOT, "--tracker", TRACKER, "--mode", "both", "--config", str(folder / "site.yaml"),
                 "--session", str(path), "--quiet"])
    assert code == 0
    return path


@pytest.mark.slow
def test_a_mixed_session_exports_both_kinds_of_rows(mixed: Path, tmp_path: Path, capsys) -> None:
    with Session.open(mixed) as session:
        assert plan_mode(session.plan) == "both" and session.header["schema"] == 3
        assert session.outcome() == "complete"
        meas = session.to_measurements()
        plan = session.plan
    csv = tmp_path / "m.csv"
    assert main(["export", str(mixed), "--csv", str(csv)]) == 0
    assert "coarse clock offset" in capsys.readouterr().out
    back = read_measurements(csv).measurements
    assert len(back) == len(meas)
    stepped = {s.sweep for s in plan.steps if s.kind == "sweep"}
    streamed = {s.sweep for s in plan.steps if s.kind == "stream"}
    assert set(back.sweep[back.streamed]) == streamed and stepped <= set(back.sweep[~back.streamed])
    assert np.isnan(back.t[~back.streamed]).all() and not np.isnan(back.t[back.streamed]).any()
    assert int(np.sum(np.isin(back.sweep, list(stepped)))) == 6 * 12  # every stop-and-go sweep step, once
    assert back.streamed.sum() > 6000  # six streams at 250 Hz
    for joint in range(1, 7):  # each joint swept both ways
        kinds = {bool(k) for k in back.streamed[back.joint == joint]}
        assert kinds == {False, True}, joint


@pytest.mark.slow
def test_a_mixed_session_is_identified_within_its_uncertainties(mixed: Path) -> None:
    result = mixed.with_suffix(".result.yaml")
    model, doc = load_result(str(result))
    assert doc["verdict"]["status"] in ("pass", "warn")
    checks = {c["name"]: c for c in doc["verdict"]["checks"]}
    assert checks["holdout"]["status"] == "pass" and checks["timing"]["status"] == "pass"
    # the model against the simulated truth at random poses: each pose's Mahalanobis distance in the model's own
    # covariance is chi-square(3); Bonferroni over the poses keeps the false alarm at FALSE_ALARM
    truth = SimulatedRig.from_spec(ROBOT, TRACKER).truth
    q = random_poses(UR5E.limits, 20, np.random.default_rng(11))
    error = model.points(q) - points_from_joints(truth, q)
    cov = model.point_covariances(q)
    distance = np.einsum("ki,kij,kj->k", error, np.linalg.inv(cov), error)
    assert distance.max() < chi2.ppf(1 - FALSE_ALARM / len(q), 3), distance
    # the held-out poses: measured RMS near its expectation (chi-square with 3 dof per pose)
    v = validation_of(doc)
    k = 3 * v["samples"]
    ratio = (v["rms"] / v["expected_rms"]) ** 2
    assert chi2.ppf(FALSE_ALARM / 2, k) / k < ratio < chi2.ppf(1 - FALSE_ALARM / 2, k) / k, ratio
    # the clock: the offset at t_ref and the drift within 4 of their standard uncertainties of the rig's own
    with Session.open(mixed) as session:
        details = session.header["tracker"]["details"]
    clock = doc["clock"]
    t_ref = clock["t_ref_s"]
    offset = float(robot_time_of_stamps(details, t_ref)) - t_ref
    assert abs(clock["offset_s"] - offset) < 4 * clock["offset_std_s"] + 1e-6  # + the stamps' float resolution
    assert abs(clock["drift"] - (1 / (1 - 0.0008) - 1)) < 4 * clock["drift_std"] + 1e-9
    assert abs(clock["offset_s"] - offset) < 0.5e-3  # the target, for the record


@pytest.mark.slow
def test_stop_and_go_rows_check_the_streams_timing(mixed: Path, tmp_path: Path, capsys) -> None:
    step, streamed = tmp_path / "step.yaml", tmp_path / "streamed.yaml"
    assert identify_main([str(mixed), "--rows", "step", "--out", str(step)]) == 0
    assert "clock" not in yaml.safe_load(step.read_text())  # no streamed row: no clock
    assert identify_main([str(mixed), "--rows", "streamed", "--out", str(streamed)]) == 0
    with Session.open(mixed) as session:
        streamed_rows = int(session.to_measurements().streamed.sum())
    assert yaml.safe_load(streamed.read_text())["clock"]["streamed_rows"] == streamed_rows
    capsys.readouterr()
    # two independent fits (disjoint fitted rows) of one robot: no significant change (1 % false alarm)
    assert identify_main(["compare", str(step), str(streamed)]) == 0
    assert "no significant change" in capsys.readouterr().out
    # one stream's stamps 1 ms late (a tracker clock that jumped for one sweep): the streamed fit gives that sweep
    # its own offset (identify/results/clock_split.py), says so in its timing check, and still agrees with the
    # stop-and-go rows
    jumped = tmp_path / "jumped.session"
    shutil.copyfile(mixed, jumped)
    with sqlite3.connect(jumped) as db:
        stream = db.execute("SELECT s.id FROM streams s JOIN steps p ON p.plan_index = s.plan_index "
                            "WHERE p.joint = 3 AND p.kind = 'stream'").fetchone()[0]
        db.execute("UPDATE tracker_samples SET t = t + 0.001 WHERE stream = ?", (stream,))
    bad = tmp_path / "jumped.yaml"
    identify_main([str(jumped), "--rows", "streamed", "--out", str(bad)])
    doc = yaml.safe_load(bad.read_text())
    offsets = {row["sweep"]: row["offset_s"] for row in doc["clock"]["per_sweep"]}
    assert len(offsets) >= 2 and max(offsets.values()) - min(offsets.values()) == pytest.approx(1e-3, abs=2e-4)
    timing = next(c for c in doc["verdict"]["checks"] if c["name"] == "timing")
    assert timing["status"] == "warn" and "offsets differ" in timing["message"]
    capsys.readouterr()
    assert identify_main(["compare", str(step), str(bad)]) == 0
    assert "no significant change" in capsys.readouterr().out


def test_rows_of_a_kind_the_data_do_not_hold_is_one_line(tmp_path: Path, capsys) -> None:
    sample = Path(__file__).resolve().parents[2] / "identify" / "data" / "sample_ur5e.csv"
    assert identify_main([str(sample), "--rows", "streamed"]) == 2
    assert "--rows streamed: the data hold no streamed rows to fit" in _one_line(capsys.readouterr().err)


# --- resume ------------------------------------------------------------------------------------------------------


def _streams(path: Path) -> list[tuple]:
    with sqlite3.connect(path) as db:
        return db.execute("SELECT plan_index, attempt, status, superseded FROM streams ORDER BY id").fetchall()


@pytest.mark.slow
def test_a_mixed_session_resumes_after_stops_in_either_kind_of_sweep(tmp_path: Path, capsys) -> None:
    (tmp_path / "site.yaml").write_text(SITE)
    path = tmp_path / "r.session"
    # moves: 1 home, 2-13 the joint 6 stop-and-go sweep: the 8th move stops halfway
    assert main(["--robot", f"{ROBOT}?fault=protective_stop@8", "--tracker", "mock?latency=0.02", "--mode", "both",
                 "--config", str(tmp_path / "site.yaml"), "--session", str(path), "--quiet"]) == 1
    with Session.open(path) as session:
        assert session.recorded_indices() == set(range(7)) and session.next_index() == 7
    assert _streams(path) == []
    capsys.readouterr()
    assert main(["--resume", str(path), "--mode", "continuous", "--quiet"]) == 2  # a resume keeps its plan
    assert "the session's plan is both" in _one_line(capsys.readouterr().err)
    # resumed at step 7: moves 1-6 the sweep's rest, 7 the range start, 8 to the stream's start, 9 the stream
    assert main(["--resume", str(path), "--robot", f"{ROBOT}?fault=protective_stop@9", "--quiet"]) == 1
    first = _streams(path)
    assert len(first) == 1 and first[0][2] == "interrupted"
    assert main(["--resume", str(path), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "verdict:" in out and "result written" in out
    redo = [s for s in _streams(path) if s[0] == first[0][0]]
    assert redo == [(first[0][0], 1, "interrupted", 1), (first[0][0], 2, "complete", 0)]
    with Session.open(path) as session:
        assert session.outcome() == "complete" and session.next_index() is None
        meas = session.to_measurements()
        index = first[0][0]
        with sqlite3.connect(path) as db:
            current = {t for (t,) in db.execute("SELECT t.t FROM tracker_samples t JOIN streams s ON s.id = "
                                                "t.stream WHERE s.plan_index = ? AND s.attempt = 2", (index,))}
            old = {t for (t,) in db.execute("SELECT t.t FROM tracker_samples t JOIN streams s ON s.id = t.stream "
                                            "WHERE s.plan_index = ? AND s.attempt = 1", (index,))}
        sweep = session.plan.steps[index].sweep
        rows = set(meas.t[meas.sweep == sweep].tolist())
    assert old and rows and rows <= current and not rows & old  # only the redo is read
    stepped = {s.sweep for s in session.plan.steps if s.kind == "sweep" and s.joint == 6}
    assert int(np.isin(meas.sweep, list(stepped)).sum()) == 12  # the stopped step measured once, on the resume


def test_rows_step_of_a_continuous_session_without_enough_poses_is_one_line(tmp_path: Path, capsys) -> None:
    """A continuous session's stop-and-go rows are its range starts and home: too few poses for any fit, refused
    in one line (exit 2) rather than fitted into a failed verdict; with enough free poses the fit goes ahead."""
    sample = read_measurements(Path(__file__).resolve().parents[2] / "identify" / "data" / "sample_ur5e.csv")
    meas = sample.measurements
    t = np.where(meas.joint > 0, np.arange(len(meas)) * 0.01, np.nan)
    free = np.flatnonzero(meas.joint == 0)
    for kept, code in ((7, 2), (30, 0)):
        keep = (meas.joint > 0) | np.isin(np.arange(len(meas)), free[:kept])
        rows = replace(meas, t=t, streamed=meas.joint > 0).subset(keep)
        path = tmp_path / f"continuous{kept}.csv"
        path.write_text(format_measurements(rows))
        capsys.readouterr()
        assert identify_main([str(path), "--robot", "ur5e", "--rows", "step", "--holdout", "0"]) == code
        err = capsys.readouterr().err
        if code == 2:
            assert "--rows step: the stop-and-go rows are 7 poses and no sweep" in _one_line(err)
