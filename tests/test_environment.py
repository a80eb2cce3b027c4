"""The test environment has every optional package the suite needs.

Driver tests skip their file when a package is missing (`pytest.importorskip`), so that a developer with a
partial install still runs the rest. Those skips must never hide a broken install where the whole suite is
meant to run (`make test`, CI): the dev extra installs all of these, and this test fails when one is missing.
"""

from __future__ import annotations

import importlib.util

import pytest

#: import name -> the distribution that provides it (ur_rtde's pinned version: tests/drivers/ur/test_driver.py).
REQUIRED = {
    "serial": "pyserial",
    "rtde_control": "ur-rtde",
    "rtde_receive": "ur-rtde",
    "cv2": "opencv-contrib-python-headless",
    "matplotlib": "matplotlib",
    "yourdfpy": "yourdfpy",
    "hypothesis": "hypothesis",
    "CESAPI": "CESAPI",
    "xdist": "pytest-xdist",
}


@pytest.mark.parametrize(("module", "distribution"), REQUIRED.items())
def test_optional_package_is_installed(module: str, distribution: str) -> None:
    assert importlib.util.find_spec(module) is not None, (
        f"{module} ({distribution}) is missing: install the dev extra, pip install -e '.[dev]'")


def test_aruco_api_of_opencv_contrib() -> None:
    import cv2

    assert hasattr(cv2, "aruco") and hasattr(cv2.aruco, "ArucoDetector") and hasattr(cv2.aruco, "CharucoDetector"), (
        f"OpenCV {cv2.__version__} lacks the aruco module: opencv-contrib-python-headless is needed, not opencv-python")

