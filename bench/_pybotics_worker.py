"""Runs pybotics' calibration on one data set; executed by ``bench.pybotics_compare`` in a separate venv.

    /tmp/pyb-venv/bin/python bench/_pybotics_worker.py IN.npz OUT.npz

Imports only numpy, scipy and pybotics (it does not see this project). IN holds the starting model in
standard DH (``types``, ``theta``, ``d``, ``a``, ``alpha``, ``base`` 4x4, ``tool`` xyz), the fitted joint
readings ``q_fit`` and points ``p_fit`` (m), and the held-out readings ``q_check``. OUT gets the predicted
points at ``q_check``, the fit's wall time (s, ``time.perf_counter`` around ``least_squares``) and its
function-evaluation count. With ``fit`` false, only the starting model's predictions are written.

Standard DH -> pybotics' modified DH (``Rx(alpha) Tx(a) Rz(theta) Tz(d)`` per link): link 1 gets
alpha = a = 0, link i > 1 gets (alpha_{i-1}, a_{i-1}, theta_i, d_i), and the last link's ``Tx(a_n) Rx(alpha_n)``
moves into the tool matrix. Fitted (pybotics' masks): every MDH value except link 1's alpha and a (identically
zero), the 6 world-frame values and the tool position; the fit is pybotics' own ``optimize_accuracy``
(per-pose distance residuals) under ``scipy.optimize.least_squares`` with its defaults, as in pybotics'
calibration example.
"""

from __future__ import annotations

import sys
import time

import numpy as np
import scipy.optimize
from pybotics.geometry import matrix_2_vector, vector_2_matrix
from pybotics.kinematic_chain import MDHKinematicChain
from pybotics.link import PrismaticMDHLink, RevoluteMDHLink
from pybotics.optimization import OptimizationHandler, optimize_accuracy
from pybotics.robot import Robot
from pybotics.tool import Tool


def _rx(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def robot_from_dh(types: str, theta, d, a, alpha, base, tool) -> Robot:
    links = []
    for i, kind in enumerate(types):
        cls = RevoluteMDHLink if kind == "R" else PrismaticMDHLink
        prev_alpha, prev_a = (0.0, 0.0) if i == 0 else (alpha[i - 1], a[i - 1])
        links.append(cls(prev_alpha, prev_a, theta[i], d[i]))
    last = np.eye(4)
    last[0, 3] = a[-1]
    last = last @ _rx(alpha[-1])
    tcp = np.eye(4)
    tcp[:3, 3] = tool
    # the tool's rotation never moves the TP; keep the matrix a pure translation + Rx as pybotics' Euler allows
    world = vector_2_matrix(matrix_2_vector(base))
    if not np.allclose(world, base, atol=1e-9):
        raise RuntimeError("pybotics' Euler ZYX round trip does not reproduce the base")
    robot = Robot(MDHKinematicChain(links), tool=Tool(matrix=last @ tcp), world_frame=world)
    robot.joint_limits = np.array([[-1e3] * len(types), [1e3] * len(types)])
    return robot


def points(robot: Robot, q: np.ndarray) -> np.ndarray:
    return np.array([robot.fk(row)[:3, 3] for row in q])


def main(argv: list[str]) -> int:
    data = np.load(argv[1])
    types = str(data["types"])
    robot = robot_from_dh(types, data["theta"], data["d"], data["a"], data["alpha"], data["base"], data["tool"])
    if not bool(data["fit"]):  # conversion check: predictions of the given model only
        np.savez(argv[2], predicted=points(robot, data["q_check"]))
        return 0
    mask = np.ones(robot.kinematic_chain.num_parameters, dtype=bool)
    mask[:2] = False  # link 1's alpha and a: zero by construction, redundant with the world frame
    handler = OptimizationHandler(robot=robot, kinematic_chain_mask=list(mask),
                                  tool_mask=[True, True, True, False, False, False], world_mask=True)
    x0 = handler.generate_optimization_vector()
    start = time.perf_counter()
    fit = scipy.optimize.least_squares(fun=optimize_accuracy, x0=x0, args=(handler, data["q_fit"], data["p_fit"]))
    seconds = time.perf_counter() - start
    handler.apply_optimization_vector(fit.x)
    np.savez(argv[2], predicted=points(handler.robot, data["q_check"]), seconds=seconds, nfev=fit.nfev,
             status=fit.status, fitted_rms=float(np.sqrt(np.mean(fit.fun**2))))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
