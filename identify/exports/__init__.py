"""Exports of an identified model: URDF (``urdf``), the UR ROS driver's calibration (``ur_calibration``) and
Robotics Toolbox for Python, the result as JSON (``rtb``)."""
