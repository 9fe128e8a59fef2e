"""The probe list of a calibration folder: the styli the station knows
(``probes.toml``), which one is selected, and each one's last qualification
(``probes/<name>.toml``; a folder from before the list keeps ``probe.toml``).

:class:`ProbeList` works for a :class:`~cmm.calibration.service.CalibrationService`
(``service``): it reads and writes the records in the service's folder, applies a
selected probe through the service's command API (the ``configure`` verb) and
notes it in the session journal; the service's probe methods delegate here.
"""

from __future__ import annotations

from typing import Any

from .records import (PROBE_QUALIFICATIONS, PROBE_RECORD, CalibrationError, LoadedCalibration, ProbeDefinition,
                      check_probe_definition, load_probe_list, load_probe_record, now, probe_expiry, save_probe_list,
                      save_record)


DEFAULT_PROBE = "Probe1"  # the one probe of a folder without a probe list (also the I++ tool name clients know)


class ProbeList:
    """The service's probe list: listing, records, adding and selecting a probe."""

    def __init__(self, service: Any) -> None:
        self.service = service

    def use_listed(self) -> tuple[list[ProbeDefinition], str]:
        """The list's selected probe (Probe1 without a list) becomes the probe in use: its name goes with every
        hit and is on the status bar. Returns :meth:`listing`."""
        svc = self.service
        probes, selected = self.listing()
        svc.use_probe(selected)
        self.mount(next((p for p in probes if p.name == selected), None))
        return probes, selected

    def mount(self, probe: ProbeDefinition | None) -> None:
        """On the simulator the selected probe's stylus is the one that touches (its nominal tip diameter)."""
        svc = self.service
        if probe is not None and svc.host.bench is not None:
            svc.host.bench.mount_stylus(probe.tip_diameter)

    def listing(self) -> tuple[list[ProbeDefinition], str]:
        """(probes, selected) from <records>/probes.toml; without a list, one probe "Probe1" with the configured tip
        (its qualification is probe.toml). Reading it changes nothing: the service's ``load`` and :meth:`select` make the
        selected name the measurement model's ``probe_name``."""
        svc = self.service
        probes, selected = load_probe_list(svc.records_dir)
        if not probes:
            probes = [ProbeDefinition(DEFAULT_PROBE, round(2 * float(svc.host.config.probe.tip_radius), 6))]
        return probes, selected or probes[0].name

    def record(self, name: str) -> Any:
        """The last qualification of probe ``name`` (a ProbeRecord), None when it was never qualified."""
        svc = self.service
        path = svc.records_dir / PROBE_QUALIFICATIONS / f"{name}.toml"
        if not path.is_file():
            probes, _ = self.listing()
            if name != probes[0].name or not (svc.records_dir / PROBE_RECORD).is_file() or \
                    (svc.records_dir / PROBE_QUALIFICATIONS).is_dir():
                return None
            path = svc.records_dir / PROBE_RECORD  # a folder from before the probe list: probe.toml is the first probe's
        return load_probe_record(path)

    def rows(self) -> list[dict[str, Any]]:
        """The probe list for a front end: name, tip diameter, stylus, selected, and when qualified the
        qualified radius, pre-travel, date, sphere and expiry (or the problem that makes the record unusable)."""
        probes, selected = self.listing()
        today = now()[:10]
        rows = []
        for p in probes:
            row: dict[str, Any] = {"name": p.name, "tip_diameter": p.tip_diameter, "stylus": p.stylus,
                                   "selected": p.name == selected, "tip_radius": None, "pretravel": "",
                                   "qualified_on": "", "sphere": "", "expires": "", "expired": False, "problem": ""}
            try:
                rec = self.record(p.name)
            except CalibrationError as exc:
                rec, row["problem"] = None, str(exc)
            if rec is not None:
                expires = probe_expiry(rec.date)
                row.update(tip_radius=rec.tip_radius, pretravel=rec.model.describe(), qualified_on=rec.date[:10],
                           sphere=rec.artifact, expires=expires, expired=bool(expires) and expires < today)
            rows.append(row)
        return rows

    def add(self, name: str, tip_diameter: Any, stylus: Any = (0.0, 0.0, -1.0)) -> ProbeDefinition:
        """Add a stylus to the list (not selected, not qualified); CalibrationError when the entry is wrong."""
        svc = self.service
        probe = check_probe_definition(name, tip_diameter, stylus)
        probes, selected = self.listing()
        if any(p.name == probe.name for p in probes):
            raise CalibrationError(f"there is already a probe named {probe.name}: choose another name")
        self.keep_legacy_record(probes)
        save_probe_list(svc.records_dir, probes + [probe], selected)
        return probe

    def select(self, client: Any, name: str) -> str:
        """Make ``name`` the probe in use: its qualified radius and pre-travel go to the live station (through
        the ``configure`` verb) and into probe.toml; an unqualified probe gets its nominal radius and no
        pre-travel model. Returns what was applied."""
        svc = self.service
        probes, _ = self.listing()
        probe = next((p for p in probes if p.name == name), None)
        if probe is None:
            raise CalibrationError(f"there is no probe named {name!r}; the list has {', '.join(p.name for p in probes)}")
        rec = self.record(name)
        self.keep_legacy_record(probes)
        if rec is not None:
            svc._log(svc.apply(LoadedCalibration(probe=rec), client=client))
            save_record(rec, svc.records_dir / PROBE_RECORD)
            text = f"probe {name} selected: r_eff {rec.tip_radius:.5f} mm, {rec.model.describe()}"
        else:
            svc._log([self.apply_nominal(client, probe)])
            (svc.records_dir / PROBE_RECORD).unlink(missing_ok=True)  # its own record is in probes/<name>.toml
            text = f"probe {name} selected, NOT qualified: nominal radius {probe.tip_diameter / 2:.4f} mm"
        save_probe_list(svc.records_dir, probes, name)
        svc.use_probe(name)
        self.mount(probe)
        svc.status["probe"] = None if rec is None else {"date": rec.date, "tip_radius": rec.tip_radius,
                                                         "artifact": rec.artifact, "probing_speed": rec.probing_speed}
        if svc.status.get("probe") is not None:
            svc.status["probe"]["name"] = name
        svc._note(client, text)
        return text

    def apply_nominal(self, client: Any, probe: ProbeDefinition) -> str:
        """A probe never qualified: its nominal radius and no pre-travel model, applied while the machine is still."""
        svc = self.service
        from ..machine.probing import ProbeSettings
        from ..metrology.compensation import PretravelModel

        host = svc.host
        settings = ProbeSettings(probe.tip_diameter / 2, PretravelModel())
        with host.settings_lock:
            host.api.invoke(client, "configure",
                                            change=lambda setup: setattr(setup.prober, "settings", settings))
        return f"probe {probe.name} (not qualified): nominal radius {probe.tip_diameter / 2:.4f} mm"

    def keep_legacy_record(self, probes: list[ProbeDefinition]) -> None:
        """Before the probe list is first written: the existing probe.toml becomes the first probe's record."""
        svc = self.service
        qdir = svc.records_dir / PROBE_QUALIFICATIONS
        if qdir.is_dir():
            return
        rec = None
        if (svc.records_dir / PROBE_RECORD).is_file():
            try:
                rec = load_probe_record(svc.records_dir / PROBE_RECORD)
            except CalibrationError:
                rec = None
        qdir.mkdir(parents=True, exist_ok=True)
        if rec is not None:
            save_record(rec, qdir / f"{probes[0].name}.toml")
