"""A camera's latency (s from a frame's exposure to the stamp ``grab`` gives it) and the frames a stop-and-go reading
may use.

A stop-and-go reading is asked for once the arm has settled (acquire's orchestrator waits for the settling time, then
calls ``measure``), and the arm stays still until the reading returns. A frame stamped before the request time plus
the latency was exposed before the request, possibly while the arm was still arriving: averaged in, it puts the
reading where the arm was (0.6 s of latency after 0.42 s of stillness: 14 mm off), while the reading's sigma, from
the frames' scatter, cannot tell. The tracker therefore skips every frame stamped before ``request + latency``
(:class:`FreshFrames`), both times on the clock of the source's ``grab`` stamps:

- the simulated camera (drivers/camera/renderer.py): the rig's clock at delivery (the source's ``now()``);
- a local camera (drivers/camera/sources.py ``LiveCamera``) and a network camera's MJPEG stream: the host's
  ``time.time()`` when the frame arrived; a snapshot URL: the middle of its request (the camera takes the image
  while it answers: latency 0 unless it answers with an older frame it kept);
- replays (a video file, images): the time the file was read; recorded frames have no live timing, and a replay
  refuses ``latency=``.

A source whose ``grab`` gave the device's own exposure time would need ``stamp >= request`` on the device's clock
instead; none does (a local camera's device times, CAP_PROP_POS_MSEC, are used for streams only). Streams are not
filtered: their rows keep their stamps and a continuous session fits the constant delay as a clock offset.

The latency used (:func:`latency_in_use`): ``latency=`` when given, else the source's own ``latency`` (the simulated
camera's; a network camera's measured one where it is a latency: drivers/camera/network.py), else 0 (a local
camera's default: give ``latency=`` for one that buffers frames). It must stay below the tracker's ``timeout``: the
wait for it counts against the wait for the reading's first frame.
"""

from __future__ import annotations

import time
from typing import Any


def latency_in_use(declared: float | None, source: Any) -> tuple[float, str]:
    """The latency (s) a tracker skips frames by and where it comes from (one phrase): ``declared`` (``latency=``)
    when given, else the source's own ``latency`` and ``latency_basis``, else 0."""
    if declared is not None:
        return declared, "latency= option"
    own = getattr(source, "latency", None)
    if own is None:
        return 0.0, "not given: 0 for a local camera or a replay"
    return float(own), str(getattr(source, "latency_basis", "the source's"))


class FreshFrames:
    """The stamps a stop-and-go measurement may use: those at or after its request time plus ``latency`` (s),
    on the clock of ``source``'s ``grab`` stamps (its ``now()``, else the host's ``time.time()``)."""

    def __init__(self, source: Any, latency: float) -> None:
        self.source, self.latency = source, latency
        self.requested = self.first = -float("inf")
        self.skipped = 0  # frames skipped in the current reading

    def request(self) -> None:
        """A measurement is asked for now: frames delivered before ``now + latency`` were exposed before it."""
        now = getattr(self.source, "now", None)
        self.requested = float(now()) if now is not None else time.time()
        self.skipped = 0
        self.first = self.requested + self.latency

    def fresh(self, stamp: float) -> bool:
        """Whether a frame stamped ``stamp`` was exposed after the request (counts the skipped ones)."""
        if stamp >= self.first:
            return True
        self.skipped += 1
        return False

    def time_left(self, stamp: float, timeout: float) -> float:
        """What is left (s) of ``timeout`` from the request after a skipped frame stamped ``stamp``."""
        return self.requested + timeout - stamp

    def note(self) -> str:
        """The current reading's skipped frames, for its status ("" for none), and a new count begins."""
        skipped, self.skipped = self.skipped, 0
        if not skipped:
            return ""
        return f"{skipped} frames exposed before the request skipped: latency {self.latency:g} s"
