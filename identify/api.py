"""The Python API for notebooks and scripts: the objects the commands use, behind a few functions.

>>> from identify import api
>>> meas = api.load_measurements("identify/data/sample_ur5e.csv")     # a CSV or a session file
>>> result = api.calibrate(meas, robot="ur5e")                           # identify (the verdict says if to trust it)
>>> result.verdict                                                       # 'pass' | 'warn' | 'fail'
>>> comp = api.compensate(result, targets)                               # joint values reaching TP targets (tracker)
>>> comp.solution.q, comp.solution.status, comp.expected                 # per target: joints, status, 1-sigma error
>>> api.compare([api.load_result("jan.yaml"), api.load_result("mar.yaml")]).verdict

Units: metres and radians; frames: the tracker's unless a name says ``base`` (DH frame 0 of the robot). Errors in
the inputs raise :class:`common.errors.InputError` (one-line messages, as the commands print them).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import ArrayLike, NDArray

from common.errors import InputError
from common.outputs import write_output
from identify.applications.calibrated import CalibratedModel, ResultError, nominal_name, recorded_model, robot_model
from identify.applications.compare import CompareError, Comparison, check_same_robot
from identify.applications.compare import compare as _compare
from identify.applications.compensate import Compensation, controller_poses, ur_pose
from identify.applications.compensate import compensate as _compensate
from identify.estimator.measurements import Measurements
from identify.io.result_io import result_to_dict
from identify.results.pipeline import Identification, identify, split_holdout

Array = NDArray[np.float64]

__all__ = ["Result", "calibrate", "compare", "compensate", "controller_pose_strings", "load_measurements",
           "load_result", "load_verification"]


@dataclass(frozen=True)
class Result:
    """A calibration: the result ``document`` (what ``identify --out`` writes), its ``model`` (forward model with
    covariance: every prediction goes through it), the ``identification`` when made in this session (None when
    loaded from a file) and the nominal ``robot`` (RobotModel) when known."""

    document: dict[str, Any]
    model: CalibratedModel
    identification: Identification | None = None
    robot: Any = None

    @property
    def verdict(self) -> str:
        """``pass``, ``warn`` or ``fail`` (see ``document["verdict"]["checks"]`` for why)."""
        return str((self.document.get("verdict") or {}).get("status"))

    def predict(self, q: ArrayLike) -> Array:
        """Predicted TP (k, 3), tracker frame, at joint readings ``q`` (k, n)."""
        return self.model.points(np.atleast_2d(np.asarray(q, dtype=float)))

    def expected_errors(self, q: ArrayLike) -> Array:
        """Expected 3D error (k,) of those predictions (1 sigma, covariance and model error), m."""
        return self.model.expected_errors(np.atleast_2d(np.asarray(q, dtype=float)))

    def save(self, path: str | Path, force: bool = False) -> None:
        """Write the result YAML (never over an existing file without ``force``)."""
        write_output(path, yaml.safe_dump(self.document, sort_keys=False, width=120), force=force)


def load_measurements(path: str | Path, joints: str | None = None, units: str | None = None) -> Measurements:
    """The measurements of a CSV (README.md, File contracts; ``joints``/``units`` as ``identify --joints/--units``)
    or of an acquisition session."""
    from identify.io.csvio import read_measurements
    from identify.io.session_measurements import read_session
    from session.schema import is_session_file

    if is_session_file(Path(path)):
        return read_session(Path(path))[0].measurements
    return read_measurements(str(path), joints, units).measurements


def calibrate(meas: Measurements, robot: str | None = None, noise: float | None = None, holdout: float = 0.3,
              seed: int = 0) -> Result:
    """Identify ``meas`` (against the nominal model ``robot``, e.g. ``"ur5e"`` or a YAML path), holding out
    ``holdout`` of the free poses (seeded) to validate; ``noise`` the tracker's, m per axis, when known."""
    from identify.sensors.evidence import checked, documented, for_estimator

    model = robot_model(robot)
    nominal = None if model is None else model.nominal
    rows = for_estimator(split_holdout(meas, holdout, seed))  # a flange camera's rows turned round
    ident, scale = checked(identify(rows.meas, nominal, noise=noise), rows, nominal)
    doc = documented(result_to_dict(ident, nominal, None if model is None else model.name,
                                    nominal_model=None if model is None else model.document), rows, scale, ident,
                   None if model is None else model.limits)
    return Result(doc, CalibratedModel.from_identification(ident), ident, model)


def load_result(path: str | Path) -> Result:
    """A result YAML written by ``identify --out`` (or :meth:`Result.save`)."""
    from identify.io.result_io import load_result as _load

    try:
        model, doc = _load(str(path))
    except ResultError as exc:
        raise InputError(str(exc)) from None
    return Result(doc, model, None, robot_model(nominal_name(doc), recorded_model(doc), str(path)))


def compensate(result: Result, targets: ArrayLike, seeds: ArrayLike | None = None, frame: str = "tracker",
               rotations: ArrayLike | None = None, tool: ArrayLike | None = None) -> Compensation:
    """Joint values that bring the real arm to ``targets`` (k, 3): TP positions in the tracker frame, or with
    ``frame="base"`` positions of ``tool`` (3,) (default the TP; flange frame) in the robot's base frame, with
    ``rotations`` (k, 3, 3) of the flange times nothing else to hold the orientation too. ``seeds`` (k, n) default
    to the robot's home. Seeded by the nominal model's solution where the robot is known, within its limits."""
    targets = np.atleast_2d(np.asarray(targets, dtype=float))
    robot, model = result.robot, result.model
    n = model.n_joints
    home = robot.home if robot is not None else np.array((result.document.get("axis_lines") or {}).get("home")
                                                         or np.zeros(n))
    seeds = np.tile(home, (len(targets), 1)) if seeds is None else np.atleast_2d(np.asarray(seeds, dtype=float))
    if frame not in ("tracker", "base"):
        raise InputError(f"frame must be 'tracker' or 'base', got {frame!r}")
    base = np.eye(4) if frame == "base" else model.base
    nominal = None if robot is None else CalibratedModel.exact(replace(robot.nominal, base=base, tool=model.tool()))
    return _compensate(model.with_base(base), targets, seeds, None if robot is None else robot.limits,
                       None if rotations is None else np.asarray(rotations, dtype=float),
                       None if tool is None else np.asarray(tool, dtype=float), None, nominal, frame)


def controller_pose_strings(result: Result, q: ArrayLike, tcp: ArrayLike | None = None) -> list[str]:
    """The UR poses ``p[x, y, z, rx, ry, rz]`` the controller (nominal model) must be given so that the real arm
    goes to ``q`` (k, n), for the tool centre point ``tcp`` (3,) in the flange frame (default: the TP)."""
    if result.robot is None:
        raise InputError("the controller's model is unknown: the result names no nominal robot")
    nominal = CalibratedModel.exact(result.robot.nominal)
    tcp = result.model.tool() if tcp is None else np.asarray(tcp, dtype=float)
    q_dh = result.model.dh_values(np.atleast_2d(np.asarray(q, dtype=float)))
    return [ur_pose(p) for p in controller_poses(nominal, q_dh, tcp)]


def compare(results: list[Result], labels: list[str] | None = None, alpha: float = 0.01, poses: int = 500,
            seed: int = 0) -> Comparison:
    """Change over time of calibrations of one robot, oldest first (``identify compare``)."""
    labels = labels or [f"#{k + 1}" for k in range(len(results))]
    models = [r.model for r in results]
    try:
        check_same_robot(models, [nominal_name(r.document) for r in results], labels)
        robot = next((r.robot for r in results if r.robot is not None), None)
        return _compare(models, labels, None if robot is None else robot.limits, alpha, poses, seed)
    except CompareError as exc:
        raise InputError(str(exc)) from None


def load_verification(path: str | Path) -> dict[str, Any]:
    """The summary of an ``acquire verify`` run (``SESSION.verify.yaml``): AP/RP per pose before and after (m)."""
    from identify.io.verification_io import read_verification

    return read_verification(str(path))
