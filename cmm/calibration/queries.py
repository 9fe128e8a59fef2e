"""The calibration's read-only queries of the command API (open to every client, anonymous observers too),
registered where the calibration lives: ``calibration_run`` (the routine running, paused or waiting for the ball
bar), ``calibration_records`` (the records on disk and what was applied from them), ``calibration_certificate``
(the artifact certificate a routine uses and why it cannot run); the probe list is the ``probes`` query of :mod:`cmm.calibration.verbs`.

The composition root (:mod:`cmm.station`) calls :func:`register_calibration_queries` with the API and the
:class:`~cmm.calibration.service.CalibrationService` it built; each result is plain data."""

from __future__ import annotations

from typing import Any


def register_calibration_queries(cmds: Any, calibration: Any) -> None:
    def run(client: Any) -> dict[str, Any]:
        return {"running": calibration.running, "paused": calibration.paused, "holding": calibration.holding,
                "instruction": calibration.instruction, "resumable": calibration.checkpoint is not None}

    def records(client: Any) -> dict[str, Any]:
        return {"directory": str(calibration.records_dir), "records": calibration.records(),
                "in_force": calibration.in_force(), "qualified_probing_speed": calibration.qualified_probing_speed}

    def certificate(client: Any, routine: str = "probe") -> dict[str, Any]:
        return {"text": calibration.certificate_text(routine), "problem": calibration.certificate_problem(routine)}

    cmds.register("calibration_run", run, {},
                  "the calibration routine now: running, paused (a probe qualification held after the point in "
                  "progress), holding (it holds the machine between two points), instruction (the ball-bar set-up "
                  "the operator is asked to place, \"\" when none waits) and resumable (a qualification a fault "
                  "stopped, to resume with its points kept)", query=True)
    cmds.register("calibration_records", records, {},
                  "the calibration records on disk (directory; records: kind, date, result), what the station "
                  "applied from them (in_force) and the qualified probing speed (mm/s) manual hits are taken at",
                  query=True)
    cmds.register("calibration_certificate", certificate, {"routine": "probe"},
                  "the artifact certificate(s) a routine (probe, iso, geometry, servo) uses, as one line of "
                  "markdown (text), and why the routine cannot run with them (problem; None: it can)", query=True)
