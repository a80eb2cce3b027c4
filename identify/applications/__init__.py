"""What a calibration is used for (pure): compensation, comparison over time, checks on new data, ISO 9283 figures."""
