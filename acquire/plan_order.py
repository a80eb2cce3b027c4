"""The order in which a continuous plan visits its sweeps and its stop-and-go poses (pure, no devices).

A sweep is travelled from one end to the other, in either direction; a pose is a single configuration. The
tour starts and ends at home. Its cost is the time of the moves between the visits (each a joint-space move at
the given speeds and accelerations; the sweeps' own time and the poses' settle and samples do not depend on the
order). :func:`order_visits` builds the tour by nearest neighbour (from where the arm is, the visit whose entry is
quickest to reach) and then improves it by local moves until none shortens it: turning one sweep round, moving
one visit elsewhere, or reversing a stretch of the tour (its sweeps turned round with it). With at most a dozen
visits this takes milliseconds; it is not guaranteed optimal, but never longer than the nearest-neighbour tour.

Collisions are not this module's business: the caller checks every move of the chosen tour against the cell and
routes a move that would come too close through home (:func:`acquire.plan_continuous.build_continuous_plan`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
MoveTime = Callable[[Array, Array], float]


@dataclass(frozen=True)
class Visit:
    """One visit of a tour: ``item`` indexes the sweeps (``sweep`` True, then ``reverse``: travelled from its end
    to its start) or the poses."""

    sweep: bool
    item: int
    reverse: bool = False


def _ends(visit: Visit, sweeps: Sequence[tuple[Array, Array]], poses: Sequence[Array]) -> tuple[Array, Array]:
    if not visit.sweep:
        return poses[visit.item], poses[visit.item]
    a, b = sweeps[visit.item]
    return (b, a) if visit.reverse else (a, b)


def tour_time(tour: Sequence[Visit], home: Array, sweeps: Sequence[tuple[Array, Array]], poses: Sequence[Array],
              move_time: MoveTime) -> float:
    """Seconds of the moves of ``tour`` from home, between its visits and back home."""
    here, total = home, 0.0
    for visit in tour:
        entry, leave = _ends(visit, sweeps, poses)
        total += move_time(here, entry)
        here = leave
    return total + move_time(here, home)


def order_visits(home: Array, sweeps: Sequence[tuple[Array, Array]], poses: Sequence[Array],
                 move_time: MoveTime) -> list[Visit]:
    """The tour (module docstring) over every sweep ((start, end) joint vectors) and every pose, from and back to
    ``home``; ``move_time(a, b)`` is the time (s) of the move from ``a`` to ``b``."""
    todo = [Visit(True, i) for i in range(len(sweeps))] + [Visit(False, i) for i in range(len(poses))]
    tour: list[Visit] = []
    here = home
    while todo:
        options = [(v, r) for v in todo for r in ((False, True) if v.sweep else (False,))]
        costs = [move_time(here, _ends(Visit(v.sweep, v.item, r), sweeps, poses)[0]) for v, r in options]
        v, r = options[int(np.argmin(costs))]
        todo.remove(v)
        tour.append(Visit(v.sweep, v.item, r))
        here = _ends(tour[-1], sweeps, poses)[1]
    return _improve(tour, home, sweeps, poses, move_time)


def _improve(tour: list[Visit], home: Array, sweeps: Sequence[tuple[Array, Array]], poses: Sequence[Array],
             move_time: MoveTime) -> list[Visit]:
    """Local moves (module docstring) while one shortens the tour by more than a millisecond."""
    best = tour_time(tour, home, sweeps, poses, move_time)
    improved = True
    while improved:
        improved = False
        for candidate in _neighbours(tour):
            t = tour_time(candidate, home, sweeps, poses, move_time)
            if t < best - 1e-3:
                tour, best, improved = candidate, t, True
                break
    return tour


def _neighbours(tour: list[Visit]) -> Iterator[list[Visit]]:
    n = len(tour)
    for i, v in enumerate(tour):
        if v.sweep:
            yield [*tour[:i], Visit(True, v.item, not v.reverse), *tour[i + 1:]]
    for i in range(n):
        rest = tour[:i] + tour[i + 1:]
        yield from ([*rest[:k], tour[i], *rest[k:]] for k in range(n) if k != i)
    for i in range(n):
        for k in range(i + 2, n + 1):
            yield tour[:i] + [Visit(v.sweep, v.item, not v.reverse) if v.sweep else v
                              for v in reversed(tour[i:k])] + tour[k:]
