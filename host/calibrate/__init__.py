"""Calibration of a gyro north finder from its own recordings (``northfinder calibrate``)."""
