"""A camera on the flange seeing a fixed board (``# sensor: flange``): its rows turned round for the estimator.

A ``flange`` row is the board's pose in the camera's frame: origin ``t`` (m) and rotation ``R`` (the measured
``x,y,z`` and ``rx,ry,rz``). The estimator fits a device fixed in the cell that measures a frame on the robot, so each
row is inverted: the **device frame is the board's** and the **target frame is the camera's**, turned round as

    rotation  Rᵀ                  (the camera's axes in the board frame)
    position  Rᵀ (c - t)          (a point c fixed to the camera, in the board frame)

Which point c of the camera: the estimator weighs a row's position and orientation as independent, isotropic
errors. The camera measures ``t`` with error δt and ``R`` with a small turn δφ (camera frame); the inverted position
errs by ``Rᵀ (δφ × (c - t) - δt)``, which shares δφ with the inverted orientation unless ``c ≈ t``. So c is the
**view point**: the median of the board's positions in the camera frame over the fit rows (where the camera looks,
at the distance it sees the board from); the board stays near it when the plan keeps it in view, and the leftover
``|c - t|·σ_r`` is added to each row's sigma: ``σ' = sqrt(σ² + ⅔ |c - t|² σ_r²)`` (the turn's part per axis).

The fit then gives, in the result's contract keys, ``base`` = board frame ← DH frame 0 and ``tool_frame`` = the
view-point frame (the camera's axes at c) in the last DH frame; :func:`flange_frames` writes what the user wants from
them: ``sensor_frame`` (the camera in the last DH frame: the hand-eye transform), ``target`` (the board in the
base frame, DH frame 0) and the ``view_point`` c. Units: metres, radians.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from common.errors import InputError
from identify.estimator.measurements import Measurements
from identify.estimator.orientation import matrices_from_rotvecs
from identify.estimator.poe import points_from_lines, target_rotations

Array = NDArray[np.float64]

def turned_round(meas: Measurements, view_point: Array | None = None) -> tuple[Measurements, Array]:
    """``meas`` of a flange camera (the board's pose in the camera frame on every row) as the estimator's rows (the
    camera's view-point frame in the board frame, module docstring), and the view point c (3,), m, camera frame
    (``view_point`` when given, else the fit rows' median). InputError unless every row has an orientation with
    ``sigma`` and ``sigma_r``: a position alone cannot be turned round."""
    if meas.rotvec is None or not np.all(meas.oriented):
        missing = meas.row[~meas.oriented][0] if meas.rotvec is not None else meas.row[0]
        raise InputError(f"line {int(missing)}: a '# sensor: flange' row needs the board's orientation (rx, ry, rz): "
                         "the camera's pose is the board's turned round")
    if meas.sigma is None or meas.sigma_r is None or not np.all(np.isfinite(meas.sigma_r)):
        raise InputError("'# sensor: flange' rows need sigma and sigma_r (the board pose's uncertainties)")
    rotation = matrices_from_rotvecs(meas.rotvec)
    t = meas.points
    fit = ~meas.check
    c = np.median(t[fit] if np.any(fit) else t, axis=0) if view_point is None else np.asarray(view_point, dtype=float)
    inverse = np.swapaxes(rotation, 1, 2)
    points = np.einsum("mij,mj->mi", inverse, c[None, :] - t)
    lever = np.linalg.norm(t - c, axis=1)
    sigma = np.sqrt(meas.sigma**2 + (2.0 / 3.0) * lever**2 * meas.sigma_r**2)
    return replace(meas, points=points, rotvec=-meas.rotvec, sigma=sigma, sensor="fixed"), c


def flange_frames(section: dict[str, Any], view_point: Array) -> dict[str, Any]:
    """What a flange camera's result adds to a model ``section`` of the result (its ``base``: board ← DH frame 0;
    ``tool_frame``: the view-point frame in the last DH frame): ``sensor_frame`` (4x4, last DH frame ← camera),
    ``target`` (4x4, DH frame 0 ← board) and ``view_point`` (3,), row-major lists."""
    tool_frame = np.array(section["tool_frame"], dtype=float)
    shift = np.eye(4)
    shift[:3, 3] = -np.asarray(view_point, dtype=float)
    return {"sensor_frame": (tool_frame @ shift).tolist(),
            "target": np.linalg.inv(np.array(section["base"], dtype=float)).tolist(),
            "view_point": np.asarray(view_point, dtype=float).tolist()}


def flange_document(doc: dict[str, Any], view_point: Array) -> dict[str, Any]:
    """The result document ``doc`` of turned-round rows with the flange camera's keys (``sensor: flange``, and
    :func:`flange_frames` at the top level and in ``extensions.model``), the contract keys kept as they are."""
    out = dict(doc)
    out["sensor"] = "flange"
    out.update(flange_frames(doc, view_point))
    out["sensor_note"] = ("a camera on the flange: base is the board frame <- DH frame 0 and tool the camera's view "
                          "point (view_point, camera frame) in the last DH frame; sensor_frame is the camera in the "
                          "last DH frame, target the board in DH frame 0")
    model = (out.get("extensions") or {}).get("model")
    if isinstance(model, dict) and "tool_frame" in model:
        out["extensions"] = {**out["extensions"], "model": {**model, **flange_frames(model, view_point)}}
    return out


def frame_point_jacobian(written: Any, q: Array, offset: Array, step: float = 1e-7) -> Array:
    """(m, 3, k): the predicted position (m, board frame) of the point ``offset`` (3,), m in the target frame (a
    flange camera's view-point frame: the camera's axes at the view point; e.g. the flange or the camera's centre),
    at DH joint values ``q`` (m, n), by the ``written`` model's (:class:`identify.results.written.WrittenModel`,
    plain) k axis-line parameters (its covariance's first k), by central differences of ``step``."""
    problem = written.problem
    k = problem.n_lines
    q = np.atleast_2d(np.asarray(q, dtype=float))
    offset = np.asarray(offset, dtype=float)

    def predict(x_lines: Array) -> Array:
        x = np.zeros(problem.size)
        x[:k] = x_lines
        lines, _ = problem.lines(x)
        return points_from_lines(lines, q) + np.einsum("mij,j->mi", target_rotations(lines, q), offset)

    return np.stack([(predict(e * step) - predict(-e * step)) / (2 * step) for e in np.eye(k)], axis=2)
