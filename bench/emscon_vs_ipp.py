"""A Leica tracker over emScon against the same sessions over I++ DME, both against the UR controller emulator
(issue 38's "done when").

    python -m bench.emscon_vs_ipp [--runs 2] [--step-scale 10] [--noise 5e-5] [--keep DIR]

One UR controller emulator (tests/ur_emulator, the real ur_rtde client in the UR driver's worker) per mode and run,
and beside it two simulated trackers measuring its one arm with the same noise per axis: the emScon server of
``emscon:`` (drivers/trackers/emscon_sim.py: stationary measurements of 1 s on the emulator's clock; continuous
measurement by time, each point stamped with the tracker's own clock) and an I++ DME server (tests/ipp_device.py:
``Get`` points; ``OnMoveReportE`` reports at the rate asked, stamped by the client on arrival). Every session is
``acquire --robot ur5e@HOST --tracker emscon:127.0.0.1:PORT`` (or ``ipp://127.0.0.1:PORT``) ``--mode MODE --yes`` as a
fresh process with the default plan and site, identified by ``acquire`` itself:

- stop-and-go at emulator time scale ``--step-scale`` (the arm ``K`` times faster; still readings do not depend on
  the wall clock), RTDE at its default rate;
- continuous at time scale 1 (I++ reports are stamped with the host's clock, so its stream is right only in real
  time), RTDE at the e-Series' native 500 Hz, the tracker asked for the site's 250 points per second.

Figures per session: the held-out RMS the result states (its check poses, validation only) and the error of the
identified model against the emulator's true arm at 200 random poses ("truth"). Per mode, pooled over the runs
(square root of the mean square), emScon / I++ for both; target: <= 1.1 (issue 38). Run r uses noise seed r for both
trackers: the two protocols see the same noise draws where they take their readings in the same order (a paired
comparison: what differs is the protocol, its timing and the stamps). Robot times are not compared (at a time scale
above 1 they include the host's waits multiplied by it; bench/ur_continuous.py measures them at real speed).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.ur_continuous import NATIVE, run_session, summary
from tests.ur_emulator import EmulatorProcess

TARGET = 1.1  # emScon / I++ accuracy, pooled per mode
TRACKERS = ("ipp", "emscon")


def _pooled(values: list[float]) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def one_mode(mode: str, run: int, noise: float, scale: float, folder: Path) -> dict[str, dict]:
    """Both trackers' sessions of ``mode`` on one emulator; their summaries (bench.ur_continuous.summary)."""
    continuous = mode == "continuous"
    rate = NATIVE if continuous else 125.0
    out = {}
    with EmulatorProcess(time_scale=1.0 if continuous else scale, native_rate=continuous, rate=rate) as emu:
        for name in TRACKERS:
            port = emu.serve_ipp(noise, run) if name == "ipp" else emu.serve_emscon(noise, run)
            tracker = f"ipp://127.0.0.1:{port}" if name == "ipp" else f"emscon:127.0.0.1:{port}"
            where = folder / f"{mode}-{name}-{run}"
            where.mkdir()
            out[name] = summary(run_session(mode, emu, tracker, rate, where, 1.0 if continuous else scale))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.emscon_vs_ipp", description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=2, help="runs, each a stop-and-go and a continuous session per tracker")
    p.add_argument("--step-scale", type=float, default=10.0, help="emulator time scale of the stop-and-go sessions")
    p.add_argument("--noise", type=float, default=5e-5, help="both trackers' noise per axis, m (default 5e-5)")
    p.add_argument("--keep", type=Path, help="keep the sessions, results and runs.json in this (new) folder")
    args = p.parse_args(argv)
    if args.runs < 1 or not args.step_scale > 0 or not 0 < args.noise < 1e-2:
        print("bench.emscon_vs_ipp: --runs >= 1, --step-scale > 0, --noise in (0, 0.01) m", file=sys.stderr)
        return 2
    if args.keep is not None and args.keep.exists():
        print(f"bench.emscon_vs_ipp: --keep {args.keep} exists; give a new folder", file=sys.stderr)
        return 2
    print(f"python {platform.python_version()}, {os.cpu_count()} cores, {time.strftime('%Y-%m-%d %H:%M %Z')}, load "
          f"{' '.join(f'{x:.1f}' for x in os.getloadavg())}; noise {args.noise * 1e3:g} mm per axis; stop-and-go at "
          f"time scale {args.step_scale:g}, continuous in real time (RTDE {NATIVE:g} Hz)")
    runs: dict[str, list[dict]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for run in range(args.runs):
            for mode in ("step", "continuous"):
                for name, r in one_mode(mode, run, args.noise, args.step_scale, folder).items():
                    runs.setdefault(f"{mode} {name}", []).append(r)
                    print(f"run {run} {mode:<10} {name:<6} wall {r['wall']:6.1f} s  "
                          f"samples {r['samples']:6d}  held-out {r['held_out'] * 1e3:.4f} mm (expected "
                          f"{r['expected'] * 1e3:.4f})  truth {r['truth_rms'] * 1e3:.4f} mm  {r['verdict']}"
                          + (f"  clock {r['clock']['offset_std_s'] * 1e3:.4f} ms std, drift "
                             f"{r['clock']['drift'] * 1e6:+.2f} ppm" if r["clock"] else ""), flush=True)
                (folder / "runs.json").write_text(json.dumps(runs, indent=1))
    ok = True
    for mode in ("step", "continuous"):
        ipp, emscon = runs[f"{mode} ipp"], runs[f"{mode} emscon"]
        held = _pooled([r["held_out"] for r in emscon]) / _pooled([r["held_out"] for r in ipp])
        truth = _pooled([r["truth_rms"] for r in emscon]) / _pooled([r["truth_rms"] for r in ipp])
        met = held <= TARGET and truth <= TARGET
        ok = ok and met
        mm = {name: {key: _pooled([r[key] for r in rows]) * 1e3 for key in ("held_out", "truth_rms")}
              for name, rows in (("emScon", emscon), ("I++", ipp))}
        print(f"{mode}: emScon / I++ pooled over {args.runs} run(s): held-out {held:.3f}, against the truth "
              f"{truth:.3f} (target <= {TARGET}: {'met' if met else 'MISSED'}); held-out emScon "
              f"{mm['emScon']['held_out']:.4f} mm, I++ {mm['I++']['held_out']:.4f} mm; against the truth emScon "
              f"{mm['emScon']['truth_rms']:.4f} mm, I++ {mm['I++']['truth_rms']:.4f} mm")
    print(f"load average after: {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
