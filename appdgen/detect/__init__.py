"""Calibration check from straight edges: how far a believed calibration is from the camera that took the frames
(APPD, bend and parameter offsets with their uncertainty), per frame and per sequence. See detector.py."""
from __future__ import annotations

from appdgen.detect.baseline import Baseline
from appdgen.detect.detector import DEFAULT_SEQUENCE, DEFAULT_THRESHOLD_PCT, Detector, Evidence, Reading

__all__ = ["DEFAULT_SEQUENCE", "DEFAULT_THRESHOLD_PCT", "Baseline", "Detector", "Evidence", "Reading"]
