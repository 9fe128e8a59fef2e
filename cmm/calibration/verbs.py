"""The calibration's verbs of the command API, registered where the calibration lives: ``qualify`` runs a
routine (its result returned, nothing applied), ``save_calibration``, ``accept_gains`` and ``select_probe``
change the live machine through the ``configure`` verb and are the calibrating holder's, as are ``add_probe``,
``set_sphere_certificate`` and ``bar_placed`` (the page's entries and the operator's answer to a set-up); the ``probes``
query reads the probe list.

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

    def probes(client: Any) -> dict[str, Any]:
        folder = None if calibration.directory is None else str(calibration.directory)
        try:
            return {"probes": calibration.probes(), "folder": folder, "problem": ""}
        except Exception as exc:  # noqa: BLE001 - an unreadable list is told, the folder still known
            return {"probes": [], "folder": folder, "problem": str(exc) or type(exc).__name__}
    cmds.register("probes", probes, {},
                  "the probe list (the Calibration tab's): per probe its name, tip diameter, stylus, selected (the one "
                  "in use), and when qualified its radius, pre-travel, date, sphere and expiry; folder: where the "
                  "records are kept (None: nowhere, so no probe of the list can be chosen); problem: why the list "
                  "cannot be read (empty when it can)", query=True)
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


    cmds.register("add_probe", calibrating(lambda client, name, tip_diameter, stylus=(0.0, 0.0, -1.0): _probe_row(
                      calibration.add_probe(name, tip_diameter, stylus))),
                  {"name": REQUIRED, "tip_diameter": REQUIRED, "stylus": (0.0, 0.0, -1.0)},
                  "add a stylus to the probe list (not selected, not qualified): name, tip diameter (mm), stylus "
                  "vector I J K from the head to the tip; returns its name, tip diameter and stylus")

    def certificate(client: Any, diameter: Any, serial: str, uncertainty_um: Any, form_um: Any = 0.0,
                    certified: str | None = None) -> dict[str, Any]:
        cert = calibration.set_sphere_certificate(diameter=diameter, serial=serial,
                                                  uncertainty=float(uncertainty_um) / 1000.0,
                                                  form=float(form_um or 0.0) / 1000.0, client=client,
                                                  certified=certified or None)
        return {"text": cert.describe(), "diameter": cert.diameter, "serial": cert.serial,
                "uncertainty_um": cert.uncertainty * 1000.0, "form_um": cert.form * 1000.0, "certified": cert.certified}
    cmds.register("set_sphere_certificate", calibrating(certificate),
                  {"diameter": REQUIRED, "serial": REQUIRED, "uncertainty_um": REQUIRED, "form_um": 0.0,
                   "certified": None},
                  "write the reference sphere's certificate as printed (diameter mm, serial, U k=2 and form in um, "
                  "its date YYYY-MM-DD; none: today) where qualification and the ISO test read it; refused with a "
                  "sentence when an entry is wrong (the previous certificate stays)")
    cmds.register("bar_placed", calibrating(lambda client: calibration.bar_placed()), {},
                  "the operator clamped the ball bar for the set-up the geometry routine shows: it goes on; false "
                  "when no set-up waits")


def _probe_row(probe: Any) -> dict[str, Any]:
    return {"name": probe.name, "tip_diameter": probe.tip_diameter, "stylus": list(probe.stylus)}
