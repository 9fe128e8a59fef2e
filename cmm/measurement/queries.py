"""Read-only queries of the measurement model for every front end (the OPC UA server, scripts): snapshots that
change nothing, registered on the command API beside the measurement verbs (``query=True``: open to every
client, anonymous observers too)."""

from __future__ import annotations

from typing import Any


def register_queries(api: Any, measurement: Any, calibration: Any = None) -> None:
    """``probe_in_use``: the probe in use; ``characteristics``: the session's toleranced characteristics; ``report_info``:
    the report header."""

    def probe(client: Any) -> dict[str, Any]:
        row: dict[str, Any] = {}
        if calibration is not None:
            try:
                row = next((r for r in calibration.probes() if r["selected"]), {})
            except Exception:  # noqa: BLE001 - an unreadable probe list: the probe in use is still named
                row = {}
        radius = row.get("tip_radius")
        status = "not qualified" if radius is None else ("expired" if row.get("expired") else "qualified")
        return {"name": measurement.probe_name or row.get("name", ""), "tip_diameter": row.get("tip_diameter"),
                "tip_radius": radius, "qualified_on": row.get("qualified_on", ""), "status": status}

    def characteristics(client: Any) -> list[dict[str, Any]]:
        from ..metrology.measured import feature_values

        with measurement.lock:
            records = [f.record() for f in measurement.features.values()]
        out = []
        for m in feature_values(records):
            out.append({"name": m.name, "value": m.value, "nominal": m.nominal, "lower": m.lower, "upper": m.upper,
                        "unit": m.unit, "ok": m.ok})
        return out

    api.register("probe_in_use", probe, {}, "the probe in use: name, tip diameter and qualified radius (mm), the date "
                 "of its qualification and its status: qualified, expired or not qualified", query=True)
    api.register("characteristics", characteristics, {},
                 "the live session's toleranced characteristics (as the report lists them): name, value, "
                 "nominal, lower and upper limits, unit and ok (None: no limit)", query=True)
    api.register("report_info", lambda client: dict(measurement.info), {},
                 "the report header (part number, drawing, operator, machine name, temperature, remarks)", query=True)
