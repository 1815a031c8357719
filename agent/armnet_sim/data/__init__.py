"""Calibration files shipped for the simulated arms (package data)."""
