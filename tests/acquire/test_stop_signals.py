"""SIGTERM and SIGHUP stop ``acquire`` as Ctrl-C does, and a stop at start-up is one line: real processes of the
installed ``acquire`` console script, real signals. (Not ``python -m``: CPython then reports a KeyboardInterrupt
caught inside an import's ``exec`` as death by SIGINT, whatever the code returns.)"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from acquire.commands.cli import main
from acquire.running.session import Session
from tests._fast_site import fast_site
from tests._session_steps import recorded_steps

pytestmark = pytest.mark.realtime  # timing-sensitive: make test runs these alone, after the rest
ROBOT = "mock:ur5e?seed=3"
SMALL = ["--steps", "12", "--samples", "3", "--free-poses", "6", "--quiet"]
COMMAND = [str(Path(sys.executable).with_name("acquire"))]
# real-time steps of a fraction of a second (full-speed moves, no settling): the stop lands mid-plan within a second
# or two of the command's start-up instead of after the default moves' and settling's seconds
FAST_SITE = fast_site()


def _handler_installed(pid: int, signum: int, timeout: float = 20.0) -> None:
    """Wait until process ``pid`` catches ``signum`` (Linux: the SigCgt mask of /proc/PID/status), so that a delay
    counts from the first line of the command's own code, not from a loaded machine's interpreter start-up."""
    status = Path(f"/proc/{pid}/status")
    deadline = time.monotonic() + timeout
    while status.exists() and time.monotonic() < deadline:
        caught = next((line.split()[1] for line in status.read_text().splitlines() if line.startswith("SigCgt:")), "0")
        if int(caught, 16) >> (signum - 1) & 1:
            return
        time.sleep(0.005)


@pytest.mark.slow
@pytest.mark.parametrize(("signum", "said"), [(signal.SIGTERM, "stopped by SIGTERM"),
                                              (signal.SIGHUP, "stopped by SIGHUP")])
def test_sigterm_and_sighup_stop_the_run_like_ctrl_c(tmp_path, capsys, signum, said):
    """Mid-plan (a real-time mock run): exit 130, one line naming the signal and the resume command, the run
    recorded aborted with the signal as its reason; the resume records the remaining steps, each once."""
    path, site = tmp_path / "s.session", tmp_path / "fast.yaml"
    site.write_text(FAST_SITE)
    proc = subprocess.Popen([*COMMAND, "--robot", ROBOT, "--tracker", "mock", *SMALL, "--realtime", "--config",
                             str(site), "--session", str(path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    deadline = time.monotonic() + 60
    while recorded_steps(path) < 2 and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.01)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130, err
    lines = err.splitlines()
    assert len(lines) == 1 and said in lines[0] and f"resume with: acquire --resume {path}" in lines[0], err
    with Session.open(path) as session:
        assert session.outcome() == "aborted"
        assert said in session.runs()[-1].reason
        done = len(session.recorded_indices())
        total = len(session.plan.steps)
    assert 2 <= done < total
    assert main(["--resume", str(path), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert f"resuming {path}: {done} of {total} steps recorded; run 1 aborted ({said}" in out
    with Session.open(path) as session:
        assert session.outcome() == "complete"
        assert sorted(s.plan_index for s in session.steps()) == list(range(total))


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
@pytest.mark.parametrize("delay", [0.0, 0.6])
def test_a_stop_during_start_up_is_one_line_without_a_traceback(tmp_path, signum, delay):
    """While the command imports, plans and connects (a dry run of a real-robot plan is the same start-up without
    moving), a stop gives one line and exit 130, never a traceback."""
    proc = subprocess.Popen([*COMMAND, "--robot", ROBOT, "--tracker", "mock", *SMALL, "--realtime",
                             "--session", str(tmp_path / "s.session")], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    _handler_installed(proc.pid, signal.SIGTERM)  # ours (Python catches SIGINT itself from its start-up on)
    time.sleep(delay)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=30)
    assert "Traceback" not in err, err
    assert proc.returncode == 130, err
    assert len(err.splitlines()) == 1 and err.startswith("acquire: "), err


@pytest.mark.slow
def test_sigterm_in_a_flange_cameras_locate_phase_stops_the_arm_and_records_nothing(tmp_path):
    """The locate moves (a real-time mock run, about 15 s) stop at SIGTERM: exit 130, one line, no session."""
    import os

    spec = ("aruco:sim?mount=flange&board=charuco&cols=11&rows=8&square=0.025&size=0.018&width=640&height=360"
            "&distance=0.45&frames=1")
    path = tmp_path / "s.session"
    proc = subprocess.Popen([*COMMAND, "--robot", ROBOT, "--tracker", spec, "--camera-mount", "0,-0.06,0.04,0,0,90",
                             "--realtime", "--quiet", "--yes", "--session", str(path)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    assert proc.stdout is not None
    for line in proc.stdout:  # the locate phase is shown before it moves
        if line.startswith("locate phase:"):
            break
    time.sleep(2.0)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130, err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("acquire: locate aborted: stopped by SIGTERM"), err
    assert not path.exists()
