"""Calibration routines: probe qualification, ISO 10360-5 probing test, machine geometry, servo tuning.

Every routine takes ``progress: Callable[[float, str], None] | None`` (fraction 0..1, a
sentence for the operator), returns a result dataclass and saves nothing by itself:
the caller (CLI or UI wizard) saves a record with ``records.save_record`` and applies it.
"""

from .records import CalibrationError  # noqa: F401
