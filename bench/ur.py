"""UR driver overhead against the controller emulator (tests/ur_emulator), with the real ur_rtde 1.6.5 client
in the driver's worker process.

    python -m bench.ur [--moves 30] [--calls 3000]

1. Worker request cost: one ``snapshot`` round trip (link, timestamp, modes, actual q and qd, program state)
   between the driver and its ur_rtde worker, against ``getActualQ`` called on an in-process
   ``RTDEReceiveInterface`` (what the driver did before the worker).
2. Worker start (``connect``: dashboard probe, factory calibration, worker with both interfaces, stream seen
   advancing) and recovery after the worker is killed (the next ``read_joints`` with a fresh worker).
3. Per move, on the emulator's real-time clock (time scale 1), ``--moves`` moves of 0.05 rad on joint 1 at
   1 rad/s, 2 rad/s² (0.32 s of motion): command to motion start (from the ``move_joints`` call to the start
   of the emulated motion), end detection (from the end of the emulated motion to ``move_joints``
   returning), and settle detection (``wait_until_still(0.1 s)`` wall time beyond its 0.1 s).
   Target: per-step overhead (start + end + settle) < 50 ms, i.e. under 1 % of a typical 5 s step.
"""

from __future__ import annotations

import argparse
import os
import platform
import signal
import statistics
import sys
import time

import numpy as np

from config.robots import load_robot
from drivers.registry import open_robot
from tests.ur_emulator import EmulatorProcess

TARGET_STEP_MS = 50.0
SETTLE = 0.1  # s


def _ms(values: list[float]) -> str:
    return (f"median {statistics.median(values) * 1e3:7.3f} ms, p95 {np.percentile(values, 95) * 1e3:7.3f} ms, "
            f"max {max(values) * 1e3:7.3f} ms")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.ur", description=__doc__.splitlines()[0])
    parser.add_argument("--moves", type=int, default=30)
    parser.add_argument("--calls", type=int, default=3000)
    args = parser.parse_args(argv)
    import rtde_receive

    print(f"python {platform.python_version()}, ur_rtde 1.6.5 client, emulator at time scale 1, "
          f"{time.strftime('%Y-%m-%d')}")
    home = np.array(load_robot("ur5e").home, dtype=float)
    with EmulatorProcess(time_scale=1.0) as emu:
        robot = open_robot(f"ur5e@{emu.host}")
        started = time.perf_counter()
        robot.connect(10.0)
        connect = time.perf_counter() - started
        try:
            calls = []
            for _ in range(args.calls):
                t = time.perf_counter()
                robot._snapshot()
                calls.append(time.perf_counter() - t)
            direct_interface = rtde_receive.RTDEReceiveInterface(emu.host)
            direct = []
            for _ in range(args.calls):
                t = time.perf_counter()
                direct_interface.getActualQ()
                direct.append(time.perf_counter() - t)
            direct_interface.disconnect()
            print(f"worker snapshot request:          {_ms(calls)}")
            print(f"in-process getActualQ (no worker): {_ms(direct)}")
            os.kill(robot._worker.pid, signal.SIGKILL)
            t = time.perf_counter()
            robot.read_joints()
            recovery = time.perf_counter() - t
            print(f"connect {connect * 1e3:.0f} ms; recovery after a killed worker (fresh worker, next read) "
                  f"{recovery * 1e3:.0f} ms")

            start_lag, end_lag, settle_lag, duration = [], [], [], []
            for k in range(args.moves):
                target = home + np.array([0.05 if k % 2 == 0 else 0.0, 0, 0, 0, 0, 0])
                t_call = time.time()
                robot.move_joints(target, [1.0] * 6, [2.0] * 6, timeout=10.0)
                t_return = time.time()
                t0, length = emu.last_motion()
                start_lag.append(t0 - t_call)
                end_lag.append(t_return - (t0 + length))
                duration.append(length)
                t = time.perf_counter()
                robot.wait_until_still(SETTLE, 5.0)
                settle_lag.append(time.perf_counter() - t - SETTLE)
        finally:
            robot.close()
    print(f"per move of 0.05 rad ({statistics.median(duration) * 1e3:.0f} ms of motion), {args.moves} moves:")
    print(f"  command to motion start   {_ms(start_lag)}")
    print(f"  motion end to return      {_ms(end_lag)}")
    print(f"  settle detection beyond {SETTLE:g} s  {_ms(settle_lag)}")
    step = statistics.median(start_lag) + statistics.median(end_lag) + statistics.median(settle_lag)
    ok = step * 1e3 < TARGET_STEP_MS
    print(f"per-step overhead (medians summed): {step * 1e3:.1f} ms, target < {TARGET_STEP_MS:g} ms: "
          f"{'ok' if ok else 'MISSED'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
