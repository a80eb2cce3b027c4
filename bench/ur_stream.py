"""The UR joint stream against the controller emulator at real speed (time scale 1), with the real ur_rtde 1.6.5
client in the driver's worker process.

    python -m bench.ur_stream [--moves 4] [--rate 500] [--travel 2.0]

The emulator sends one RTDE package every 1 / ``--rate`` s on its clock (``native_rate``: e-Series 500 Hz by
default). Per streamed move (``start_move`` of ``--travel`` rad on joint 1 at 1 rad/s, 2 rad/s²,
``read_joint_stream`` every 50 ms until ``motion_done``): the rate achieved (samples per controller second),
packages lost (inside recorded gaps: none may be lost silently, checked here too), and the CPU time of the worker
process (``/proc/PID/stat``, user + system) per second of streaming, against the same worker idle (stream off).
Target: no package lost silently. Reported: packages lost inside recorded gaps (``RTDEReceiveInterface`` keeps only
the latest package, so packages that arrive in a burst faster than the recorder polls are lost; the emulator
counts the packages it sent late, which reach the client in such bursts), and the worker's CPU.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import numpy as np

from config.robots import load_robot
from drivers.registry import open_robot
from tests.ur_emulator import EmulatorProcess


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of process ``pid`` so far, s (Linux /proc)."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.ur_stream", description=__doc__.splitlines()[0])
    parser.add_argument("--moves", type=int, default=4)
    parser.add_argument("--rate", type=float, default=500.0)
    parser.add_argument("--travel", type=float, default=2.0)
    args = parser.parse_args(argv)
    if args.moves < 1 or not 0 < args.rate <= 500 or not 0 < args.travel <= 3:
        print("bench.ur_stream: --moves >= 1, 0 < --rate <= 500, 0 < --travel <= 3", file=sys.stderr)
        return 2
    home = np.array(load_robot("ur5e").home, dtype=float)
    period = 1.0 / args.rate
    print(f"python {platform.python_version()}, ur_rtde 1.6.5 client, emulator at time scale 1, {args.rate:g} Hz "
          f"native, {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}, {time.strftime('%Y-%m-%d')}")
    ok = True
    with EmulatorProcess(time_scale=1.0, rate=args.rate, native_rate=True) as emu:
        robot = open_robot(f"ur5e@{emu.host}?rtde_frequency={args.rate:g}")
        robot.connect(10.0)
        try:
            pid = robot._worker.pid
            c0, w0 = cpu_seconds(pid), time.monotonic()
            time.sleep(2.0)
            idle = (cpu_seconds(pid) - c0) / (time.monotonic() - w0)
            print(f"worker idle (no stream): {idle * 100:.1f} % of a core")
            for k in range(args.moves):
                target = home + np.array([args.travel if k % 2 == 0 else 0.0, 0, 0, 0, 0, 0])
                c0, w0, late0 = cpu_seconds(pid), time.monotonic(), emu.get("late_packages")
                robot.start_joint_stream(5.0)
                robot.start_move(target, [1.0] * 6, [2.0] * 6, 30.0)
                ts, gaps = [], []
                while not robot.motion_done():
                    batch = robot.read_joint_stream()
                    ts.append(batch.t)
                    gaps += batch.gaps
                    time.sleep(0.05)
                batch = robot.stop_joint_stream(5.0)
                ts.append(batch.t)
                gaps += batch.gaps
                cpu = (cpu_seconds(pid) - c0) / (time.monotonic() - w0)
                late = emu.get("late_packages") - late0
                t = np.concatenate(ts)
                steps = np.diff(t)
                silent = int(np.sum([(a, b) not in set(gaps) for a, b, s in zip(t[:-1], t[1:], steps, strict=True)
                                     if s > 1.5 * period]))
                lost = int(sum(round((b - a) / period) - 1 for a, b in gaps))
                span = t[-1] - t[0]
                expected = round(span / period) + 1
                ok = ok and silent == 0 and len(t) + lost == expected
                print(f"move {k + 1}: {span:.2f} s controller time, {len(t)} samples = "
                      f"{(len(t) - 1) / span:.1f} Hz kept of {args.rate:g}; lost in {len(gaps)} recorded gap(s): "
                      f"{lost}; silent drops {silent}; worker CPU {cpu * 100:.1f} % of a core "
                      f"({robot.stream_stats['polls'] / max(span, 1e-9):.0f} polls/s); emulator packages sent late "
                      f"(both connections): {late}")
        finally:
            robot.close()
    print("target (no silent drop: every package kept or inside a recorded gap): " + ("met" if ok else "MISSED"))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
