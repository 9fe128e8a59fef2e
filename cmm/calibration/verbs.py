"""The calibration's verbs of the command API, registered where the calibration lives: ``qualify`` runs a
routine (its result returned, nothing applied), ``save_calibration``, ``accept_gains`` and ``select_probe``
change the live machine through the ``configure`` verb and are the calibrating holder's; the
``calibration_state`` query is what the status bar and the jog show of it.

The composition root (:mod:`cmm.station`) calls :func:`register_calibration_verbs` with the API, the control
core's access check and the :class:`~cmm.calibration.service.CalibrationService` it built."""

from __future__ import annotations

from typing import Any, Callable


def register_calibration_verbs(cmds: Any, check_access: Callable[[Any, str], None], calibration: Any) -> None:
    """Register the calibration verbs on the command API ``cmds``; ``check_access(client, "calibrate")`` refuses a
    client that may not calibrate (the control core's rule)."""
    REQUIRED = cmds.REQUIRED  # noqa: N806 - the API's marker of a parameter that must be given

    def qualify(client: Any, routine: str = "probe", progress: Any = None, options: dict | None = None) -> Any:
        return calibration.run(client, routine, progress, **(options or {}))
    cmds.register("qualify", qualify, {"routine": "probe", "progress": None, "options": None},
                  "run a calibration routine: probe (qualification), iso (ISO 10360-5), geometry, servo; "
                  "returns its result, nothing applied; cancel ends it")

    def calibrating(fn: Any) -> Any:  # the calibration service's changes: the holder's, sent as its client
        def verb(client: Any, **params: Any) -> Any:
            check_access(client, "calibrate")
            return fn(client, **params)
        return verb

    cmds.register("save_calibration", calibrating(
                      lambda client, routine, result, accepted=False: calibration.save(client, routine, result,
                                                                                       accepted=accepted)),
                  {"routine": REQUIRED, "result": REQUIRED, "accepted": False},
                  "in process: write a routine's result (qualify's) as its record; a probe qualification and a "
                  "machine geometry are also applied to the live machine (through configure); returns "
                  "(path, applied)")
    cmds.register("accept_gains", calibrating(lambda client, result: calibration.accept_gains(client, result)),
                  {"result": REQUIRED},
                  "in process: send a servo tuning's proposed gains to the modules (through configure) and "
                  "record them; returns the record's path")
    cmds.register("select_probe", calibrating(lambda client, name: calibration.select_probe(client, str(name))),
                  {"name": REQUIRED},
                  "make a probe of the list the one in use: its qualified radius and pre-travel (or its nominal "
                  "radius) go to the live machine; returns what was applied")
    cmds.register("calibration_state", lambda client: {
                      "holding": bool(calibration.holding), "probe": calibration.status.get("probe"),
                      "probing_speed": float(calibration.qualified_probing_speed)}, {},
                  "the calibration as the status bar shows it: holding (a paused qualification holds the machine "
                  "between two points), the probe qualification in force (None: not qualified) and the qualified "
                  "probing speed (mm/s) manual hits are taken at", query=True)
