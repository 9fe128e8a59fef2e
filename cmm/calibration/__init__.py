"""Calibration routines: probe qualification, ISO 10360-5 probing test, machine geometry, servo tuning.

Every routine takes ``progress: Callable[[float, str], None] | None`` (fraction 0..1, a
sentence for the operator), returns a result dataclass and saves nothing by itself:
the caller saves a record with ``records.save_record`` and applies it: on a station that is
:class:`~cmm.calibration.service.CalibrationService` (``station.calibration``, used by the
Calibration tab), which runs the routines through the command API; ``cmm calibrate`` runs them
on a machine of its own.
"""

from .records import CalibrationError  # noqa: F401
