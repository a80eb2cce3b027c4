"""The controller's factory calibration: UR's DH values as the project's DHModel, read back from a session
header (old sessions and robots without one included), and shown against the identified model."""

from __future__ import annotations

import json

import numpy as np
import pytest

from config.robots import load_robot
from identify.applications.factory import factory_model, factory_reference
from kinematics.dh import points_from_joints
from session.rows import factory_calibration

NOMINAL = load_robot("ur5e").nominal


def _calibration(model=NOMINAL) -> dict[str, list[float]]:
    """What the UR controller sends (drivers/ur/info.py): full DH values per joint, theta the zero offset."""
    return {key: list(map(float, getattr(model, key))) for key in ("theta", "a", "d", "alpha")} | {
        "checksum": [1, 2, 3, 4, 5, 6], "status": 1}


def test_ur_values_map_one_to_one_onto_the_forward_model() -> None:
    model = factory_model(_calibration(), "RRRRRR")
    np.testing.assert_array_equal(model.dh_table(), NOMINAL.dh_table())
    # UR's documented zero pose of the UR5e: the flange at x = a2 + a3, y = -(d4 + d6), z = d1 - d5
    np.testing.assert_allclose(points_from_joints(model, np.zeros((1, 6)))[0], [-0.8172, -0.2329, 0.0628],
                               atol=1e-12)


def test_theta_is_the_joint_zero_offset() -> None:
    """A controller calibrated with theta_2 = +0.01 rad puts the arm where the nominal one is at q_2 + 0.01."""
    calibration = _calibration()
    calibration["theta"][1] = 0.01
    model = factory_model(calibration, "RRRRRR")
    q = np.array([[0.3, -1.2, 1.1, -0.5, 0.7, 0.2]])
    shifted = q + np.array([0, 0.01, 0, 0, 0, 0])
    np.testing.assert_allclose(points_from_joints(model, q), points_from_joints(NOMINAL, shifted), atol=1e-12)


@pytest.mark.parametrize(("change", "message"), [
    (lambda c: c.pop("alpha"), "no numeric 'alpha'"),
    (lambda c: c.update(d=[0.1] * 5), "'d' must be 6 finite numbers"),
    (lambda c: c.update(a=[float("nan")] * 6), "'a' must be 6 finite numbers"),
    (lambda c: c.update(a=[425.0] + [0.0] * 5), "not a DH table"),  # millimetres are not metres
])
def test_a_malformed_calibration_is_refused_in_one_line(change, message) -> None:
    calibration = _calibration()
    change(calibration)
    with pytest.raises(ValueError, match=message):
        factory_model(calibration, "RRRRRR")
    reference, note = factory_reference(calibration, "", "RRRRRR")
    assert reference is None and note.startswith("factory calibration: not usable") and "\n" not in note


def test_session_header_calibration_old_sessions_and_robots_without_one() -> None:
    calibration = _calibration()
    header = {"robot": {"details": {"host": "10.0.0.2", "factory_calibration": json.dumps(calibration)}}}
    assert factory_calibration(header) == (calibration, "")
    unavailable = {"robot": {"details": {"factory_calibration": "unavailable (the controller sends no kinematics "
                                                                "info on port 30001)"}}}
    value, note = factory_calibration(unavailable)
    assert value is None and "sends no kinematics info" in note
    for old in ({"robot": {"model": "simulated ur5e", "details": {}}}, {"robot": {"model": "ur5e"}}, {}):
        assert factory_calibration(old) == (None, "")  # nothing to report, nothing said
        assert factory_reference(*factory_calibration(old), "RRRRRR") == (None, "")
    reference, note = factory_reference(*factory_calibration(header), "RRRRRR")
    assert reference is not None and reference[0] == "factory calibration" and note == ""
    assert factory_reference(None, "why", "RRRRRR") == (None, "factory calibration: not available (why)")
