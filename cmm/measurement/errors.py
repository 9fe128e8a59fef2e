"""What front ends need of the measurement model without the model itself: its refusal (an operator's sentence)
and the names it knows (feature kinds, report header fields). The page, the I++ server and the command line
import these, never :mod:`cmm.measurement.model`."""

from __future__ import annotations

FEATURE_KINDS = ("point", "line", "plane", "circle", "sphere", "cylinder", "cone")
INFO_FIELDS = ("part_number", "drawing", "operator", "machine_name", "temperature", "remarks")


class MeasurementError(RuntimeError):
    """An action the measurement model refuses, in an operator's words."""


__all__ = ["FEATURE_KINDS", "INFO_FIELDS", "MeasurementError"]
