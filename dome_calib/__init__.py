"""Calibration and synchronisation of a massively multi-camera capture dome (Panoptic Studio style)."""
