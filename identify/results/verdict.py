"""Whether a result can be trusted: named checks with their numbers, and the verdict they add up to.

Its shape in the result YAML is fixed (other tools read it; README, "The verdict"):
``{status: pass | warn | fail, checks: [{name, status, value, limit, message}]}``.
A check passes, warns (the result is usable with the caveat its message states in numbers) or fails (do
not use the model). The verdict is the worst of its checks. Limits are stated as constants with why.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from scipy.stats import chi2

from common.units import slip_hint
from identify.estimator.adequacy import Adequacy
from identify.estimator.identifiability import LEVEL, Identifiability

if TYPE_CHECKING:
    from identify.results.clock_split import ClockSplit

STATUSES = ("pass", "warn", "fail")

GROSS_MISFIT = 0.01  # m RMS 3D: no calibrated arm, tracker or DH-able error leaves residuals this large;
#                      a wrong joint type, a unit error or mixed data sets do
CONDITION_WARN = 1e6  # column-scaled Jacobian of the minimal (line) parameters: directions known to
CONDITION_FAIL = 1e9  # < 1e-6 / 1e-9 of the best one are barely / not determined (half / all of float's digits)
HOLDOUT_ALARM = 1e-3  # false-alarm rate of the held-out test
HOLDOUT_FAIL = 3.0  # held-out RMS over its expectation beyond which the model is wrong, not just optimistic
REJECTED_WARN = 0.05  # share of samples rejected as outliers above which the data deserve a look
MISSING_WARN = 0.05  # share of the plan's steps recorded missing above which the data are not what was planned
NOMINAL_TOLERANCE = 0.01  # of the robot's size, RMS: an arm differs from its catalogue model by millimetres per metre
#                          of reach (a UR5e: 10 mm; a 4 m arm on a lifting column: 40 mm); a wrong model, a unit or a
#                          joint-order slip misses by tens of percent
UNIT_SLIP = 10.0  # residuals this many times below the declared noise: no fit beats its tracker tenfold, a noise
#                  declared in the wrong unit does (a value meant in mm read as metres is 1000x)


@dataclass(frozen=True)
class Check:
    """One named check: ``value`` against ``limit`` (units in ``message``)."""

    name: str
    status: str
    value: float | None
    limit: float | None
    message: str

    def as_dict(self) -> dict[str, object]:
        return {"name": self.name, "status": self.status, "value": self.value, "limit": self.limit,
                "message": self.message}


@dataclass(frozen=True)
class Verdict:
    """The worst status of ``checks``."""

    checks: tuple[Check, ...]

    @property
    def status(self) -> str:
        return max((c.status for c in self.checks), key=STATUSES.index, default="pass")

    def as_dict(self) -> dict[str, object]:
        return {"status": self.status, "checks": [c.as_dict() for c in self.checks]}

    def summary(self) -> str:
        """One line: the status and the messages of the checks that did not pass, failures first."""
        bad = sorted((c for c in self.checks if c.status != "pass"), key=lambda c: -STATUSES.index(c.status))
        if not bad:
            return f"verdict: pass ({len(self.checks)} checks)"
        return f"verdict: {self.status.upper()}: " + "; ".join(f"{c.name}: {c.message}" for c in bad)


def mm(value: float) -> str:
    return f"{value * 1e3:.3g} mm"


def _slip(declared: float, typed: str | None, column: bool) -> str:
    """What was given and what was probably meant, for a declared noise (m per axis) far above the residuals."""
    if column:
        return (f"the sigma column, median {mm(declared)}, is in the positions' unit: a sigma in mm beside "
                "positions in metres?")
    return slip_hint("--noise", typed if typed is not None else f"{declared:g}", declared)


def model_fit(rms_3d: float, adequacy: Adequacy, cause: str | None = None, noise_typed: str | None = None,
              noise_column: bool = False) -> Check:
    """Residuals against the noise: gross misfit fails, detected model error warns (uncertainties inflated).
    ``cause``: what the joint-error selection found (the kinds of error selected and what they explain). For the
    hint of a unit slip: ``noise_typed``, the ``--noise`` text as typed (None: the declared noise was given in
    metres); ``noise_column``, the declared noise is the data's ``sigma`` column."""
    a = adequacy
    if rms_3d > GROSS_MISFIT:
        why = (f"{cause}; a DH model with these joint errors still does not describe the data"
               if cause and "selected" in cause else
               f"{cause}: joint types, units, the robot model or mixed data sets?" if cause else
               "joint types, units, robot model or mixed data sets?")
        return Check("model_fit", "fail", rms_3d, GROSS_MISFIT,
                     f"residual RMS {mm(rms_3d)} exceeds {mm(GROSS_MISFIT)}: {why}")
    if a.declared is not None:
        reference = f"the declared tracker noise {mm(a.declared)}"
    elif a.difference is not None:
        reference = f"the noise of successive differences along the sweeps, {mm(a.difference)}"
    else:
        reference = "no independent noise estimate (no sweeps to difference)"
    if a.declared is not None and a.residual * UNIT_SLIP < a.declared:
        return Check("model_fit", "warn", a.residual, a.declared / UNIT_SLIP,
                     f"residuals {mm(a.residual)} per axis are {a.declared / a.residual:.3g}x below {reference}: "
                     f"a unit slip? ({_slip(a.declared, noise_typed, noise_column)}); the uncertainties, and the "
                     "limits compensation and verification take from them, are that much too loose")
    if a.detected and a.model_error == 0.0:  # the excess does not follow the arcs: nothing the predictions share
        found = f"; {cause}" if cause else ""
        return Check("model_fit", "warn", a.white, None,
                     f"residuals {mm(a.residual)} per axis vs {reference} ({a.statistic:.3g} > {a.limit:.3g}): an "
                     f"excess of {mm(a.white)} per axis that does not follow the arcs (noise above the declared, or "
                     f"an error too thinly sampled to show along them); uncertainties scaled to the residuals{found}")
    if a.detected:
        found = f"; {cause}" if cause else ""
        return Check("model_fit", "warn", a.model_error, None,
                     f"model error {mm(a.model_error)} per axis against tracker noise {mm(a.noise)}: residuals "
                     f"{mm(a.residual)} per axis vs {reference} ({a.statistic:.3g} > {a.limit:.3g}); uncertainties "
                     f"inflated {a.inflation:.3g}x in variance to cover it{found}")
    if a.declared is None and a.difference is None:
        return Check("model_fit", "pass", a.statistic, a.limit,
                     f"residuals {mm(a.residual)} per axis; {reference}, no declared noise (--noise): model error "
                     "cannot be told from tracker noise")
    return Check("model_fit", "pass", a.statistic, a.limit,
                 f"residuals {mm(a.residual)} per axis, consistent with {reference}")


def conditioning(condition: float, found: Identifiability | None = None, at_nominal: tuple[str, ...] = (),
                 model_error: bool = False) -> Check:
    """Whether the data determine the written parameters. ``found`` speaks of each parameter (its σ against its
    own scale, near redundancies, parameters held because the data do not separate them, a model error's reach);
    ``at_nominal``: what was held at the nominal because the data did not determine it (``model_error``: or a model
    error the fit cannot hold could move it);
    the condition number of the scaled axis-line fit only fails a numerically singular problem (and decides alone
    when ``found`` is None)."""
    if not condition < CONDITION_FAIL:
        return Check("conditioning", "fail", condition, CONDITION_FAIL,
                     f"condition number {condition:.3g}: the data do not determine every parameter (near-singular)")
    number = f" (condition number {condition:.3g} of the axis-line fit)"
    if found is None:
        status = "warn" if condition > CONDITION_WARN else "pass"
        text = ("some parameter combinations are barely determined" if status == "warn" else
                "every parameter is determined")
        return Check("conditioning", status, condition, CONDITION_WARN, text + number)
    parts = []
    poor = found.poor
    if poor:
        parts.append(f"{len(poor)} parameter(s) not determined (3 sigma moves the tracked point beyond "
                     f"{100 * LEVEL:g} % of the robot's size): " + ", ".join(p.text() for p in poor[:3])
                     + (", ..." if len(poor) > 3 else ""))
    parts.extend(f"only a combination of {', '.join(group)} is determined (near redundancy)"
                 for group in found.redundant)
    if found.held:
        parts.append(f"{', '.join(found.held)} not separated by the data from other parameters: held at their "
                     "conventional values")
    if at_nominal:  # the result is only the nominal there: right, but not a calibration of it
        cause = ", or a model error the fit cannot hold could move it," if model_error else ""
        parts.append(f"the data do not determine the model{cause} along directions that move "
                     + ", ".join(dict.fromkeys(at_nominal)) + ": held at the nominal placed on the data, its "
                     "tolerance in every stated accuracy (see fixed); poses that move those joints further, or a "
                     "second tracked point off the last axis, would determine them")
    if parts:
        return Check("conditioning", "warn", condition, CONDITION_FAIL, "; ".join(parts) + number)
    w = found.worst
    text = "every parameter is determined" + ("" if w is None else
                                              f"; the least, {w.text()}, moves the tracked point "
                                              f"{100 * w.reach:.2g} % of the robot's size at 3 sigma")
    return Check("conditioning", "pass", condition, CONDITION_FAIL, text + number)


MODEL_NAMES = {"plain": "plain model (DH)", "extended": "extended model (DH + joint errors)"}


def holdout(samples: int, rms: float, expected: float, model: str = "plain",
            others: dict[str, tuple[float, float]] | None = None, differ: float | None = None,
            unvalidated: str = "") -> Check:
    """Held-out RMS of the recommended written ``model`` (``plain`` or ``extended``) against the RMS its uncertainty
    and the noise predict (chi-square on 3k); ``others``: the other written models' held-out and expected RMS (m).
    Another model in the file that misses its own expectation warns: a reader who takes it (a DH-only reader takes
    the plain table) would get worse than the file says. ``differ`` (m): the RMS distance between the two models'
    predictions at the held-out poses (None without joint errors): the check shows an error only when it reaches
    :func:`holdout_resolution`. ``unvalidated``: why the joint errors in the file are not recommended (the plain
    model is; see :func:`recommended`), '' when they are or there are none."""
    limit = _holdout_limit(expected, samples)
    ratio = rms / expected if expected > 0 else float("inf")
    if rms > limit and ratio > HOLDOUT_FAIL:
        status = "fail"
    elif rms > limit:
        status = "warn"
    else:
        status = "pass"
    also = ""
    for name, (other, other_expected) in (others or {}).items():
        also += f"; {MODEL_NAMES.get(name, name)} {mm(other)}"
        if other > _holdout_limit(other_expected, samples):
            status = "warn" if status == "pass" else status
            also += (f", {other / other_expected:.2f}x its expected {mm(other_expected)}: do not use it"
                     + (" (the top-level table a DH-only reader takes)" if name == "plain" else ""))
    if unvalidated:
        also += f"; the joint errors are not recommended: {unvalidated}"
    elif differ is not None and model == "extended":
        also += (f"; the joint errors move the predictions there by {mm(differ)} RMS, beyond the "
                 f"{mm(holdout_resolution(expected, samples))} the {samples} poses resolve")
    return Check("holdout", status, rms, limit,
                 f"{MODEL_NAMES.get(model, model)}: held-out RMS {mm(rms)} over {samples} poses vs expected "
                 f"{mm(expected)} ({ratio:.2f}x){also}")


def holdout_orientation(samples: int, rms: float, expected: float, model: str = "plain") -> Check:
    """Held-out orientations of full-pose rows (rad): their 3D RMS rotation residual against the RMS the model's
    uncertainty and the rows' sigma_r predict, on the same chi-square test as the positions (:func:`holdout`)."""
    limit = _holdout_limit(expected, samples)
    ratio = rms / expected if expected > 0 else float("inf")
    status = "fail" if rms > limit and ratio > HOLDOUT_FAIL else "warn" if rms > limit else "pass"
    return Check("holdout_orientation", status, rms, limit,
                 f"{MODEL_NAMES.get(model, model)}: held-out orientations {rms * 1e3:.3g} mrad RMS over {samples} "
                 f"poses vs expected {expected * 1e3:.3g} mrad ({ratio:.2f}x)")


def recommended(plain: tuple[float, float], extended: tuple[float, float] | None, samples: int,
                differ: float | None) -> tuple[str, str]:
    """The model the held-out evidence supports, and why the joint errors are not it ('' when they are, or when the
    file has none). ``plain``, ``extended``: each model's held-out and expected RMS (m) over ``samples`` check poses
    (``extended`` None without joint errors, ``samples`` 0 without check rows); ``differ`` (m): the RMS distance
    between their predictions there. The extended model is recommended only when the check poses tell the models
    apart (``differ`` at least :func:`holdout_resolution`) and it predicts them better: joint errors chosen on the fit
    rows alone were never tested where they extrapolate."""
    if extended is None:
        return "plain", ""
    if samples == 0:
        return "plain", "no pose was held out to test them (the plain model is recommended; add check poses)"
    resolution = holdout_resolution(extended[1], samples)
    if differ is not None and differ < resolution:
        return "plain", (f"they move the predictions at the {samples} held-out poses by {mm(differ)} RMS, less than "
                         f"the {mm(resolution)} an error must reach for these poses to show it: not validated (the "
                         "plain model is recommended; add check poses where the joints go beyond the fitted range)")
    if extended[0] >= plain[0]:
        return "plain", (f"the extended model predicts the held-out poses to {mm(extended[0])} RMS, no better than "
                         f"the plain model's {mm(plain[0])}: not validated (the plain model is recommended)")
    return "extended", ""


def not_validated(extended: bool) -> Check:
    """The holdout check of a result with no pose held out: nothing tested the stated accuracy away from the fit
    rows, so the result is not a pass (``extended``: joint errors were selected and are not recommended)."""
    joint_errors = (" The joint errors selected on the fit rows are not recommended either: nothing tested them "
                    "where they extrapolate (the plain model is)." if extended else "")
    return Check("holdout", "warn", None, None,
                 "no pose held out: the stated accuracy is not validated. Validate it with check poses: rows with "
                 "role check, --holdout with free poses, or `identify check RESULT OTHER.session` on poses measured "
                 "apart from these." + joint_errors)


def holdout_resolution(expected: float, samples: int) -> float:
    """The RMS error (m) beyond ``expected`` that the held-out test over ``samples`` poses detects about half the
    time: the one that brings the expected held-out RMS to the test's limit."""
    limit = _holdout_limit(expected, samples)
    return float(max(limit**2 - expected**2, 0.0) ** 0.5)


def _holdout_limit(expected: float, samples: int) -> float:
    """The held-out RMS (m) beyond which ``expected`` is missed at the false-alarm rate HOLDOUT_ALARM."""
    return float(expected * (chi2.isf(HOLDOUT_ALARM, 3 * samples) / (3 * samples)) ** 0.5)


def outliers(rejected: int, samples: int, lost_sweeps: list[str]) -> Check:
    share = rejected / samples if samples else 0.0
    if lost_sweeps:
        return Check("outliers", "fail", share, REJECTED_WARN,
                     f"{', '.join(lost_sweeps)} lost most of its samples as outliers: that joint rests on too "
                     "little data")
    status = "warn" if share > REJECTED_WARN else "pass"
    return Check("outliers", status, share, REJECTED_WARN,
                 f"{rejected} of {samples} samples rejected as gross outliers ({share:.1%})")


def missing_steps(missing: int, planned: int, reasons: dict[str, int]) -> Check:
    """Steps of a session's plan recorded missing (tracker failures, a target out of a camera's view): the fit
    uses the rest, so it has less data, and fewer poses, than the plan it was designed from."""
    share = missing / planned if planned else 0.0
    status = "warn" if share > MISSING_WARN else "pass"
    kinds: dict[str, int] = {}  # reasons that differ only in their counts ("(6 of 8 frames failed)") go together
    for reason, n in reasons.items():
        kind = re.sub(r" \([^()]*\d[^()]*\)", "", reason)
        kinds[kind] = kinds.get(kind, 0) + n
    why = "; ".join(f"{n}: {r}" for r, n in sorted(kinds.items(), key=lambda item: -item[1])[:3])
    message = (f"{missing} of {planned} plan steps ({100 * share:.0f} %) recorded missing"
               + (f" ({why})" if why else "") + ("; the fit uses the rest" if missing else ""))
    return Check("missing_steps", status, share, MISSING_WARN, message)


def with_session_check(verdict: Verdict, check: Check) -> Verdict:
    """``verdict`` with ``check`` added (a session's own check, e.g. :func:`missing_steps`)."""
    return Verdict((*verdict.checks, check))


def nominal(name: str, rms: float, size: float, expected: float = 0.0) -> Check:
    """The nominal model placed on the data against the identified one: ``rms`` (m) their RMS distance at the fitted
    poses, ``size`` (m) the robot's size, ``expected`` (m) the identified model's own accuracy there. The limit
    follows the arm (:data:`NOMINAL_TOLERANCE` of its size) and the data (three times their accuracy)."""
    limit = NOMINAL_TOLERANCE * size + 3.0 * expected
    status = "fail" if rms > limit else "pass"
    text = "the data contradict the nominal model" if status == "fail" else "consistent with the nominal model"
    return Check("nominal", status, rms, limit,
                 f"nominal {name} placed on the data misses them by {mm(rms)} RMS (limit {mm(limit)}: "
                 f"{100 * NOMINAL_TOLERANCE:g} % of the robot's size {size:.3g} m): {text}")


def timing(offset_std: float, speed: float, noise: float, split: ClockSplit | None = None,
           offsets: Sequence[float] = ()) -> Check:
    """The streamed rows' clock fit: the offset's uncertainty (s) times the RMS speed of the tracked point
    (m/s) is the position error the timing leaves; it warns when that reaches the tracker noise (m). It also
    warns when the sweeps needed one offset each (``split``: :class:`identify.results.clock_split.ClockSplit`;
    ``offsets`` s, per sweep): the clocks changed their relation during the session."""
    effect = offset_std * speed
    status = "warn" if effect > noise else "pass"
    text = ("the timing is barely determined: add stop-and-go poses or sweeps with ramps" if status == "warn"
            else "the timing is determined")
    message = (f"clock offset known to {offset_std * 1e3:.3g} ms at {speed * 1e3:.3g} mm/s RMS TP speed: "
               f"{mm(effect)} of position ({text})")
    if split is not None and split.split:
        status = "warn"
        message += (f"; the streamed sweeps' clock offsets differ (score {split.statistic:.3g} > {split.limit:.3g}; "
                    f"{min(offsets) * 1e3:.3f} to {max(offsets) * 1e3:.3f} ms): each sweep was fitted with its own "
                    "offset (a clock restart, a resume or a timestamp jump between sweeps)")
    return Check("timing", status, effect, noise, message)


def dh_limit(links: int) -> float:
    """Chi-square limit of the cost a parallel-axis convention may add before it counts as measurable."""
    return float(chi2.isf(HOLDOUT_ALARM, max(links, 1)))


def dh_table(rms_gap: float, statistic: float, expected: float, capped: list[str]) -> Check:
    """Whether the written DH table reproduces the identified model (parallel-axis offset cap).

    ``statistic``: the cost the convention adds, in noise variances; chi-square with one degree of freedom
    per capped link when the axes' misalignment is only noise. ``rms_gap`` (m) the RMS difference of the
    two models' predictions at the fitted poses, ``expected`` (m) the accuracy expected there."""
    limit = dh_limit(len(capped))
    if not capped or statistic <= limit:
        text = "" if not capped else f" (convention for {', '.join(capped)} costs nothing measurable)"
        return Check("dh_table", "pass", statistic, limit,
                     f"the DH table reproduces the identified model to {mm(rms_gap)} RMS{text}")
    status = "fail" if rms_gap > HOLDOUT_FAIL * expected else "warn"
    return Check("dh_table", status, statistic, limit,
                 f"the DH table misses the identified model by {mm(rms_gap)} RMS (expected accuracy {mm(expected)}): "
                 f"the axes at {', '.join(capped)} are measurably misaligned and exact DH would put them beyond "
                 "--max-offset; raise it for exact DH, or use the axis lines in the result")
