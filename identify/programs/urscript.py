"""URScript (Universal Robots): the targets of ``movej``, ``movel``, ``movep`` and ``servoj``.

A target is the first argument of one of these calls: a joint list ``[q1, ..., qn]`` (rad), a pose
``p[x, y, z, rx, ry, rz]`` (m, axis-angle rad, robot base frame), or the name of a variable assigned such a
literal exactly once and used by motion commands only (the literal is then rewritten where it is assigned).
Everything else that moves the arm is listed with its reason and kept as written: poses computed at run time
(``pose_trans``, ``pose_add``, ...), values read from the controller (``get_actual_tcp_pose()``, ...), variables
assigned more than once, named poses other code also uses, ``movec``. A literal ``set_tcp(p[...])`` gives the
program's tool centre point. Comments (``#``) and strings are never read as code.
"""

from __future__ import annotations

import re

import numpy as np

from identify.applications.compensate import parse_ur_pose, rotvecs
from identify.programs.core import Array, Parsed, Skipped, Target, line_of, line_text

name = "urscript"
NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
LIST = re.compile(rf"\[\s*{NUMBER}(?:\s*,\s*{NUMBER})*\s*\]")
POSE = re.compile(rf"p\s*{LIST.pattern}")
MOVES = ("movej", "movel", "movep", "servoj")
CALL = re.compile(r"\b(movej|movel|movep|servoj|movec)\s*\(")
ASSIGN = re.compile(r"(?m)^[ \t]*(?:(?:global|local)[ \t]+)?([A-Za-z_]\w*)[ \t]*=(?!=)[ \t]*")
SET_TCP = re.compile(r"\bset_tcp\s*\(")
RUN_TIME = (("pose_", "a pose computed at run time ({word} chain)"),
            ("get_", "a value read from the controller at run time ({word})"))


def mask(text: str) -> str:
    """``text`` with comments and the insides of strings blanked (same length, line endings kept)."""
    out = list(text)
    quote = None
    comment = False
    for i, c in enumerate(text):
        if c in "\r\n":
            comment, quote = False, None
            continue
        if comment:
            out[i] = " "
        elif quote:
            if c == quote:
                quote = None
            else:
                out[i] = " "
        elif c == "#":
            comment, out[i] = True, " "
        elif c in "\"'":
            quote = c
    return "".join(out)


def _argument(code: str, start: int) -> tuple[int, int]:
    """Span of the first argument of a call whose ``(`` ends just before ``start``, stripped of blanks."""
    depth, i = 0, start
    while i < len(code):
        c = code[i]
        if c in "([":
            depth += 1
        elif c in ")]":
            if depth == 0:
                break
            depth -= 1
        elif c == "," and depth == 0:
            break
        i += 1
    a, b = start, i
    while a < b and code[a].isspace():
        a += 1
    while b > a and code[b - 1].isspace():
        b -= 1
    return a, b


def _literal(code: str, a: int, b: int, n_joints: int) -> tuple[str, tuple[float, ...]] | None:
    body = code[a:b]
    if POSE.fullmatch(body):
        return "pose", tuple(float(v) for v in re.findall(NUMBER, body[body.index("["):]))
    if LIST.fullmatch(body):
        values = tuple(float(v) for v in re.findall(NUMBER, body))
        return ("joints", values) if len(values) == n_joints else None
    return None


def _why(expression: str) -> str:
    for prefix, reason in RUN_TIME:
        word = re.search(rf"\b{prefix}\w*", expression)
        if word:
            return reason.format(word=word.group(0))
    return "a target computed at run time"


def parse(text: str, n_joints: int) -> Parsed:
    """The targets of a URScript program for an arm of ``n_joints`` (see the module docstring), with the TCP it
    sets (``tcp_problem`` when it sets several or computes one)."""
    code = mask(text)
    assigned: dict[str, list[tuple[int, int, int]]] = {}  # name -> (offset of the name, rhs start, rhs end)
    for m in ASSIGN.finditer(code):
        end = code.find("\n", m.end())
        end = len(code) if end < 0 else end
        a, b = m.end(), end
        while b > a and code[b - 1].isspace():
            b -= 1
        assigned.setdefault(m.group(1), []).append((m.start(1), a, b))
    calls = []  # (command, call offset, argument span)
    for m in CALL.finditer(code):
        calls.append((m.group(1), m.start(), _argument(code, m.end())))
    as_target = {a for command, _, (a, b) in calls if command in MOVES and re.fullmatch(r"[A-Za-z_]\w*", code[a:b])}
    targets: dict[tuple[int, int], Target] = {}
    skipped: list[Skipped] = []

    def skip(offset: int, reason: str) -> None:
        line = line_of(text, offset)
        skipped.append(Skipped(line, line_text(text, line), reason))

    for command, offset, (a, b) in calls:
        expression = code[a:b]
        if command == "movec":
            skip(offset, "movec (a circular move through a via pose) is not rewritten by this filter")
            continue
        literal = _literal(code, a, b, n_joints)
        if literal is not None:
            targets[(a, b)] = Target(literal[0], literal[1], a, b, line_of(text, a), offset,
                                     pose=_pose(*literal))
            continue
        if not re.fullmatch(r"[A-Za-z_]\w*", expression):
            if LIST.fullmatch(expression):
                skip(offset, f"a joint list of {len(re.findall(NUMBER, expression))} values for a "
                             f"{n_joints}-joint arm")
            else:
                skip(offset, _why(expression))
            continue
        reason = _named(code, expression, assigned, as_target, n_joints)
        if reason:
            skip(offset, reason)
            continue
        _, ra, rb = assigned[expression][0]
        if (ra, rb) not in targets:
            kind, values = _literal(code, ra, rb, n_joints) or ("", ())
            targets[(ra, rb)] = Target(kind, values, ra, rb, line_of(text, ra), offset, expression,
                                       _pose(kind, values))
    return Parsed(text, sorted(targets.values(), key=lambda t: t.use), sorted(skipped, key=lambda s: s.line),
                  *_tcp(code))


def _named(code: str, word: str, assigned: dict[str, list[tuple[int, int, int]]], as_target: set[int],
           n_joints: int) -> str:
    """Why the named target ``word`` cannot be rewritten, or "" when it can."""
    places = assigned.get(word, [])
    if not places:
        return f"'{word}' is not assigned in the program (an installation variable or a parameter)"
    if len(places) > 1:
        lines = ", ".join(str(line_of(code, p)) for p, _, _ in places)
        return f"'{word}' is assigned more than once (lines {lines})"
    at, ra, rb = places[0]
    rhs = code[ra:rb]
    if _literal(code, ra, rb, n_joints) is None:
        if LIST.fullmatch(rhs):
            return f"'{word}' (line {line_of(code, at)}) is a joint list of {len(re.findall(NUMBER, rhs))} values " \
                   f"for a {n_joints}-joint arm"
        return f"'{word}' is {_why(rhs)} (line {line_of(code, at)})"
    others = [m.start() for m in re.finditer(rf"\b{re.escape(word)}\b", code) if m.start() != at
              and m.start() not in as_target]
    if others:
        return (f"the named pose '{word}' (line {line_of(code, at)}) is also used by other code (line "
                f"{line_of(code, others[0])}): rewriting it would change that too")
    return ""


def _pose(kind: str, values: tuple[float, ...]) -> Array | None:
    return parse_ur_pose("p[" + ", ".join(repr(v) for v in values) + "]") if kind == "pose" else None


def _tcp(code: str) -> tuple[tuple[float, ...] | None, str]:
    """The program's literal TCP (or None), and why it cannot be used ("" when it can)."""
    found, computed = [], []
    for m in SET_TCP.finditer(code):
        a, b = _argument(code, m.end())
        if POSE.fullmatch(code[a:b]):
            found.append(tuple(float(v) for v in re.findall(NUMBER, code[a:b][code[a:b].index("["):])))
        else:
            computed.append(line_of(code, m.start()))
    if computed:
        return None, f"the program sets its TCP at run time (set_tcp on line {computed[0]}): give it with --tool"
    if len(set(found)) > 1:
        lines = ", ".join(str(line_of(code, m.start())) for m in SET_TCP.finditer(code))
        return None, (f"the program sets {len(set(found))} different TCPs (set_tcp on lines {lines}): filter each "
                      "part with its own --tool")
    return (found[0] if found else None), ""


def joints(q: Array) -> str:
    """A URScript joint list, rad, 12 significant digits."""
    return "[" + ", ".join(f"{v:.12g}" for v in np.asarray(q, dtype=float)) + "]"


def pose(value: Array, near: tuple[float, ...] | None = None) -> str:
    """A URScript pose ``p[x, y, z, rx, ry, rz]`` (m, axis-angle rad, 12 significant digits). Of the two rotation
    vectors of one rotation (``r`` and ``r (1 - 2 pi / |r|)``), the one nearer the written pose ``near`` (its six
    numbers), so that a rotation near pi keeps the sign it was written with."""
    rv = rotvecs(np.asarray(value)[None])[0]
    angle = float(np.linalg.norm(rv))
    if near is not None and angle > 0:
        other = rv * (1.0 - 2.0 * np.pi / angle)
        if np.linalg.norm(other - np.asarray(near[3:])) < np.linalg.norm(rv - np.asarray(near[3:])):
            rv = other
    return "p[" + ", ".join(f"{v:.12g}" for v in [*np.asarray(value)[:3, 3], *rv]) + "]"


def comment(text: str) -> str:
    """An end-of-line URScript comment."""
    return f"  # {text}"
