"""The order in which a continuous plan visits its sweeps and its stop-and-go poses (pure, no devices).

A sweep is travelled from one end to the other, in either direction; a pose is a single configuration. The
tour starts and ends at home. Its cost is the time of the moves between the visits (each a joint-space move at
the given speeds and accelerations; the sweeps' own time and the poses' settle and samples do not depend on the
order). :func:`order_visits` builds the tour by nearest neighbour (from where the arm is, the visit whose entry is
quickest to reach) and then improves it by local moves until none shortens it: turning one sweep round, moving
one visit elsewhere, or reversing a stretch of the tour (its sweeps turned round with it). With at most a dozen
visits this takes milliseconds; it is not guaranteed optimal, but never longer than the nearest-neighbour tour.

Collisions are not this module's business: the caller checks every move of the chosen tour against the cell and
routes a move that would come too close through home (:func:`acquire.planning.plan_continuous.build_continuous_plan`).
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


def tour_time(tour: Sequence[Visit], home: Array, sweeps: Sequence[tuple[Array, Array]], poses: Sequence[Array],
              move_time: MoveTime) -> float:
    """Seconds of the moves of ``tour`` from home, between its visits and back home."""
    return _Costs(home, sweeps, poses, move_time).time(tour)


class _Costs:
    """The move times between every pair of the tour's points (home, each sweep's two ends, each pose), computed
    once, and a tour's time from them."""

    def __init__(self, home: Array, sweeps: Sequence[tuple[Array, Array]], poses: Sequence[Array],
                 move_time: MoveTime) -> None:
        points = [home, *(q for ends in sweeps for q in ends), *poses]
        self.first_pose = 1 + 2 * len(sweeps)
        self.table = np.array([[move_time(a, b) for b in points] for a in points])

    def ends(self, v: Visit) -> tuple[int, int]:
        if not v.sweep:
            return self.first_pose + v.item, self.first_pose + v.item
        start, end = 1 + 2 * v.item, 2 + 2 * v.item
        return (end, start) if v.reverse else (start, end)

    def time(self, tour: Sequence[Visit]) -> float:
        here, total = 0, 0.0
        for v in tour:
            entry, leave = self.ends(v)
            total += self.table[here, entry]
            here = leave
        return float(total + self.table[here, 0])


def order_visits(home: Array, sweeps: Sequence[tuple[Array, Array]], poses: Sequence[Array],
                 move_time: MoveTime) -> list[Visit]:
    """The tour (module docstring) over every sweep ((start, end) joint vectors) and every pose, from and back to
    ``home``; ``move_time(a, b)`` is the time (s) of the move from ``a`` to ``b``."""
    costs = _Costs(home, sweeps, poses, move_time)
    todo = [Visit(True, i) for i in range(len(sweeps))] + [Visit(False, i) for i in range(len(poses))]
    tour: list[Visit] = []
    here = 0
    while todo:
        options = [Visit(v.sweep, v.item, r) for v in todo for r in ((False, True) if v.sweep else (False,))]
        best = min(options, key=lambda v: costs.table[here, costs.ends(v)[0]])
        todo.remove(Visit(best.sweep, best.item))
        tour.append(best)
        here = costs.ends(best)[1]
    return _improve(tour, costs)


def _improve(tour: list[Visit], costs: _Costs) -> list[Visit]:
    """Local moves (module docstring) while one shortens the tour by more than a millisecond."""
    best = costs.time(tour)
    improved = True
    while improved:
        improved = False
        for candidate in _neighbours(tour):
            t = costs.time(candidate)
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
