"""Devices that need more than the estimator: a camera on the flange (flange.py) and a length scale (scale.py)."""
