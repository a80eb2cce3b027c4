"""Tracker protocol benchmarks: ASCII parser throughput and the serial driver's per-measurement overhead.

    python -m bench.trackers [--lines 50000] [--readings 300] [--latency 0.005] [--average 10]

1. Parser throughput: ``--lines`` valid reply lines of each bundled profile (random points, mixed line
   endings) fed in 4 kB chunks through ``LineSplitter`` and ``parse_line``. Target: >= 20,000 lines/s.
2. Per-measurement overhead: the polled profiles' simulated devices (tests/tracker_devices.py) on a real
   pseudo-terminal, answering each trigger after ``--latency`` s; the driver's ``measure(1)`` repeated
   ``--readings`` times. Overhead = median wall time per reading minus the device's median time per trigger (its
   sleep, formatting and write); it includes the driver (flush, write, read, parse) and the pty's transit
   both ways. Target: < 1 ms. The same through an RFC 2217 server (``serial:rfc2217://``, pyserial's
   PortManager bridging loopback TCP to the pty): the overhead then includes the bridge's transit.
3. I++ DME on loopback (no device latency): ms per reading for one ``Get(X(), Y(), Z())``, for a reading
   the client averages from ``--average`` points, and for one the server averages (its averaging property).
4. Leica emScon on loopback (the simulated server of drivers/trackers/emscon_sim.py, its measurement time on a
   virtual clock: no device latency): the set-up at connect, then per stationary reading (``StartMeasurement``,
   its answer and its result) the median and 95th percentile latency and the readings per second, one reading per
   ``measure`` call and ``--readings`` in one call. Target: < 1 ms per reading (the protocol's own cost).
   Continuous measurement by time at its fastest (a point every 1 ms) for ``--stream-seconds`` s on the wall
   clock, read every 20 ms as a sweep reads it: points per second delivered, their delay (the host's time when
   ``read_stream`` handed a point over minus the point's time; the server sends 10 packets a second, so up to about
   120 ms), the process's CPU time per point (the client and the emulator, which computes each point's kinematics,
   share the process), and the times to start and stop the measurement. Target: every point
   the server sent, none in a gap, 1,000 per second.
"""

from __future__ import annotations

import argparse
import random
import statistics
import sys
import time
import warnings
from typing import Any

from drivers.clock import WallClock
from drivers.registry import open_tracker
from drivers.sim.rig import SimulatedRig
from drivers.trackers.ascii_profile import LineSplitter, checksum_of, load_profile, parse_line
from drivers.trackers.ipp import IppTracker
from tests.emscon_device import EmsconServer
from tests.rfc2217_bridge import Rfc2217Bridge
from tests.tracker_devices import AsciiDevice, IppServer

PROFILES = ("polled-xyz", "stream-csv", "tracker-checksum")


def _lines(name: str, n: int, rng: random.Random) -> bytes:
    profile = load_profile(name)
    sim, out = profile.simulation, []
    for _ in range(n):
        values = {k: rng.uniform(-2.0, 2.0) / profile.scale for k in "xyz"}
        values["status"] = sim.get("ok", "OK")
        values.update(seq=len(out) + 1, t=0.004 * len(out), tp=1)  # the fields of streaming and multi-point replies
        if "payload" in sim:
            payload = str(sim["payload"]).format(**values)
            line = str(sim["reply"]).format(payload=payload, checksum=checksum_of(payload, profile.checksum or "xor"))
        else:
            line = str(sim["reply"]).format(**values)
        out.append(line.encode() + rng.choice([b"\r\n", b"\n", b"\r"]))
    return b"".join(out)


def parser_throughput(name: str, n: int) -> float:
    """Lines per second through splitter + parser (best of 3)."""
    profile, data = load_profile(name), _lines(name, n, random.Random(1))
    best = 0.0
    for _ in range(3):
        splitter, parsed = LineSplitter(), 0
        started = time.perf_counter()
        for i in range(0, len(data), 4096):
            for line in splitter.feed(data[i:i + 4096]):
                parse_line(profile, line)
                parsed += 1
        elapsed = time.perf_counter() - started
        assert parsed == n, (parsed, n)
        best = max(best, n / elapsed)
    return best


def serial_overhead(name: str, readings: int, latency: float, rfc2217: bool = False) -> tuple[float, float, float]:
    """(median wall ms per reading, median device ms per trigger, median overhead ms) over the pty, directly
    or through an RFC 2217 server (``rfc2217``)."""
    with AsciiDevice(name, latency=latency) as device:
        bridge = Rfc2217Bridge(device.port) if rfc2217 else None
        url = bridge.url if bridge is not None else device.port
        try:
            tracker = open_tracker(f"serial:{url}?protocol={name}&timeout=1")
            tracker.connect(3.0)
            _timed_measurements(tracker, 10)
            device.busy.clear()
            walls = _timed_measurements(tracker, readings)
            tracker.close()
        finally:
            if bridge is not None:
                bridge.stop()
        busy = list(device.busy)
    # medians taken apart: the device may log a trigger's time just after the reading returned
    wall, device_time = statistics.median(walls), statistics.median(busy)
    return wall * 1e3, device_time * 1e3, (wall - device_time) * 1e3


def ipp_round_trip(readings: int, average: int = 1, server_averaging: bool = False) -> float:
    """Median ms per reading against the loopback I++ server: ``average`` points per reading, averaged by
    the server (its averaging property) or by the client."""
    with IppServer(averaging="XX.Average" if server_averaging else None) as server:
        tracker = IppTracker(server.host, server.port, average=average)
        tracker.connect(2.0)
        walls = _timed_measurements(tracker, readings)
        tracker.close()
    return statistics.median(walls) * 1e3


def emscon_loopback(readings: int) -> tuple[float, float, float, float, float]:
    """(set-up ms, median ms and 95th percentile ms per single reading, readings/s one per call, readings/s
    ``readings`` in one call) against the simulated emScon server on loopback."""
    with EmsconServer(noise=2e-5) as server:
        tracker = open_tracker(f"emscon:{server.host}:{server.port}?meas_time=0.001")
        started = time.perf_counter()
        tracker.connect(3.0)
        setup = time.perf_counter() - started
        _timed_measurements(tracker, 20)
        walls = sorted(_timed_measurements(tracker, readings))
        started = time.perf_counter()
        tracker.measure(readings, 60.0)
        batch = readings / (time.perf_counter() - started)
        tracker.close()
    return (setup * 1e3, statistics.median(walls) * 1e3, walls[int(0.95 * (len(walls) - 1))] * 1e3,
            len(walls) / sum(walls), batch)


def emscon_stream(seconds: float) -> dict[str, float]:
    """Continuous measurement by time at 1 ms against the simulated emScon server on the wall clock (module doc)."""
    rig = SimulatedRig("ur5e", seed=0, clock=WallClock())
    with EmsconServer(rig, noise=2e-5) as server:
        tracker = open_tracker(f"emscon:{server.host}:{server.port}?meas_time=0.001")
        tracker.connect(3.0)
        started = time.perf_counter()
        rate = tracker.start_stream(1000.0, 3.0)
        start_ms = (time.perf_counter() - started) * 1e3
        cpu, wall, delays, kept, gaps = time.process_time(), time.perf_counter(), [], 0, 0
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            time.sleep(0.02)
            batch = tracker.read_stream()
            now = time.time()
            delays += (now - (batch.t + server.boot)).tolist()  # tracker time + its boot = the point's host time
            kept, gaps = kept + len(batch.t), gaps + len(batch.gaps)
        started = time.perf_counter()
        last = tracker.stop_stream(3.0)
        stop_ms = (time.perf_counter() - started) * 1e3
        span = time.perf_counter() - wall
        cpu = time.process_time() - cpu
        kept, gaps = kept + len(last.t), gaps + len(last.gaps)
        sent = len(server.streamed)
        tracker.close()
    delays.sort()
    return {"rate": rate, "per_second": kept / span, "kept": kept, "sent": sent, "gaps": gaps,
            "delay_median": statistics.median(delays) * 1e3, "delay_max": delays[-1] * 1e3,
            "cpu_us": cpu / max(kept, 1) * 1e6, "start_ms": start_ms, "stop_ms": stop_ms}


def _timed_measurements(tracker: Any, count: int) -> list[float]:
    """Wall time (s) of each of ``count`` single measurements."""
    walls = []
    for _ in range(count):
        started = time.perf_counter()
        tracker.measure(1, 2.0)
        walls.append(time.perf_counter() - started)
    return walls


def main() -> int:
    """Print the measurements; exit status 1 if any target is missed."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lines", type=int, default=50_000)
    parser.add_argument("--readings", type=int, default=300)
    parser.add_argument("--latency", type=float, default=0.005, help="device response time, s")
    parser.add_argument("--average", type=int, default=10, help="I++ points per averaged reading")
    parser.add_argument("--stream-seconds", type=float, default=3.0, help="emScon continuous measurement, s")
    args = parser.parse_args()
    warnings.filterwarnings("ignore", r"set(Daemon|Name)\(\) is deprecated", DeprecationWarning)  # pyserial 3.5
    missed = False
    print("parser throughput (target >= 20,000 lines/s)")
    for name in PROFILES:
        rate = parser_throughput(name, args.lines)
        missed |= rate < 20_000
        print(f"  {name:18s} {rate:10,.0f} lines/s  {'ok' if rate >= 20_000 else 'MISSED'}")
    print(f"per-measurement overhead over a pty, device latency {args.latency * 1e3:g} ms (target < 1 ms)")
    for name in ("polled-xyz", "tracker-checksum"):
        wall, busy, overhead = serial_overhead(name, args.readings, args.latency)
        missed |= overhead >= 1.0
        print(f"  {name:18s} wall {wall:6.3f} ms  device {busy:6.3f} ms  overhead {overhead:6.3f} ms  "
              f"{'ok' if overhead < 1.0 else 'MISSED'}")
    for name in ("polled-xyz",):
        wall, busy, overhead = serial_overhead(name, args.readings, args.latency, rfc2217=True)
        missed |= overhead >= 1.0
        print(f"  {name + ' rfc2217':18s} wall {wall:6.3f} ms  device {busy:6.3f} ms  overhead {overhead:6.3f} ms  "
              f"{'ok' if overhead < 1.0 else 'MISSED'}")
    print("I++ DME on loopback, ms per reading (median)")
    print(f"  one Get(X(), Y(), Z())             {ipp_round_trip(args.readings):6.3f}")
    print(f"  client average of {args.average:3d} points      "
          f"{ipp_round_trip(args.readings // 4, args.average):6.3f}")
    print(f"  server average of {args.average:3d} points      "
          f"{ipp_round_trip(args.readings, args.average, server_averaging=True):6.3f}")
    setup, median, p95, single, batch = emscon_loopback(args.readings * 3)
    missed |= median >= 1.0
    print("Leica emScon on loopback (target < 1 ms per reading)")
    print(f"  set-up at connect (13 commands)    {setup:6.3f} ms")
    print(f"  one stationary reading             {median:6.3f} ms median, {p95:6.3f} ms 95th percentile  "
          f"{'ok' if median < 1.0 else 'MISSED'}")
    print(f"  readings per second                {single:6.0f} one per call, {batch:6.0f} with "
          f"{args.readings * 3} in one call")
    r = emscon_stream(args.stream_seconds)
    ok = r["kept"] == r["sent"] and not r["gaps"] and r["rate"] == 1000.0
    missed |= not ok
    print(f"  continuous by time, every 1 ms     {r['per_second']:6.0f} points/s over {args.stream_seconds:g} s: "
          f"{r['kept']} of the {r['sent']} sent, {r['gaps']} gaps  {'ok' if ok else 'MISSED'}")
    print(f"  delay from a point to its read     {r['delay_median']:6.1f} ms median, {r['delay_max']:6.1f} ms max; "
          f"CPU {r['cpu_us']:.0f} us per point (client and emulator together); start {r['start_ms']:.2f} ms, "
          f"stop {r['stop_ms']:.2f} ms")
    return 1 if missed else 0


if __name__ == "__main__":
    sys.exit(main())
