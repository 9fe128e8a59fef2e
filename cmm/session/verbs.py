"""The recorded sessions and the trends in the command API, registered where the sessions live.

Queries (open to every client): ``session_store`` (where the journals are, the session recording now, where
exports go), ``sessions`` (every session of the store with its counts), ``trends``, ``trend_series`` and
``trend_options`` (the series, characteristics and stations recorded), ``trend_history`` (one characteristic over a series' parts) and
``trend_charts`` (a series' control charts, as the report includes them). Verbs (the control holder's, as every
change of the record): ``rename_session``, ``delete_session`` and ``reevaluate_session``.

The composition root (:mod:`cmm.station`) calls :func:`register_session_verbs` with the API, the control core's
access check and the measurement model (its store, its live journal, its trends); this module imports neither.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

from ..journal.store import StoreError, check_name, is_url, open_store
from ..journal.writer import JournalError
from .worker import WorkerError, shared_summaries, shared_worker

REEVALUATE_METHODS = ("recorded", "ls", "minzone", "mic", "mcc")  # "recorded": each feature's own fit


def check_reevaluation(store: Any, new: str, tip_radius: float = 0.0, method: str = "recorded") -> None:
    """Refuse a re-evaluation into ``new`` (StoreError, ValueError: the operator's sentence) before it starts: a
    name that is unusable or taken, an unknown fit method, an implausible tip radius."""
    check_name(new)
    if open_store(store).exists(new):
        raise StoreError(f"a session named {new!r} already exists: choose another name")
    if method not in REEVALUATE_METHODS:
        raise ValueError(f"unknown fit method {method!r}; choose one of {', '.join(REEVALUATE_METHODS)}")
    if tip_radius and not 0 < float(tip_radius) < 50:
        raise ValueError(f"tip radius {tip_radius} mm is not plausible")


def register_session_verbs(cmds: Any, check_access: Callable[[Any, str], None], measurement: Any) -> None:
    """Register the session and trend queries and verbs on the command API ``cmds``; ``check_access(client,
    "measure")`` refuses a client that may not change the record (the control core's rule)."""
    REQUIRED = cmds.REQUIRED  # noqa: N806 - the API's marker of a parameter that must be given

    def where() -> str:
        return str(measurement.session_dir)

    def live_name() -> str | None:
        j = measurement.journal
        if j is None:
            return None
        path = getattr(j, "path", None)
        return Path(path).stem if path is not None else getattr(j, "name", None)

    def store_info(client: Any) -> dict[str, Any]:
        d = measurement.session_dir
        return {"store": where(), "url": is_url(d), "live": live_name(),
                "export_dir": "exports" if is_url(d) else str(d)}

    def sessions(client: Any, wait: bool = False) -> list[dict[str, Any]]:
        live = live_name()
        rows = []
        for info in open_store(measurement.session_dir).list():
            if info.name == live:
                with measurement.lock:
                    hits, features = len(measurement.hits), len(measurement.features)
            else:
                try:
                    summary = shared_summaries().get(where(), info.name, (info.events, info.modified), wait=wait)
                except (StoreError, JournalError, OSError, ValueError, KeyError, WorkerError) as exc:
                    summary = {"hits": "?", "features": "?", "damage": str(exc)}
                summary = summary or {"hits": "…", "features": "…"}
                hits, features = summary.get("hits"), summary.get("features")
            rows.append({"name": info.name, "events": info.events, "hits": hits, "features": features,
                         "recording": info.open_for_writing or info.name == live, "modified": info.modified})
        return rows

    def refuse_live(name: str, what: str) -> None:
        recording = name == live_name() or any(i.name == name and i.open_for_writing
                                               for i in open_store(measurement.session_dir).list())
        if recording:
            raise StoreError(f"session {name!r} is being recorded: {what}")

    def rename(client: Any, old: str, new: str) -> str:
        check_access(client, "measure")
        new = check_name(str(new).strip())
        refuse_live(old, "start a new session before you rename it")
        open_store(measurement.session_dir).rename(old, new)
        shared_summaries().forget(where(), old)
        return new

    def delete(client: Any, name: str) -> str:
        check_access(client, "measure")
        refuse_live(name, "it cannot be deleted")
        open_store(measurement.session_dir).delete(name)
        shared_summaries().forget(where(), name)
        return name

    def reevaluate(client: Any, name: str, new: str, tip_radius: float = 0.0, method: str = "recorded",
                   tolerances: Any = None) -> dict[str, Any]:
        from . import worker

        check_access(client, "measure")
        check_reevaluation(measurement.session_dir, new, tip_radius, method)
        return shared_worker().call(worker.reevaluate, where(), name, new, float(tip_radius or 0.0),
                                    None if method == "recorded" else method, tolerances)

    cmds.register("session_store", store_info, {},
                  "where the session journals are (store: a folder or a postgresql:// URL; url: whether it is one), "
                  "the session recording now (live) and the folder exports are written to (export_dir)", query=True)
    cmds.register("sessions", sessions, {"wait": False},
                  "every session of the store: name, events, hits, features, recording, modified; the counts of a "
                  "recorded session are read by the session worker once per version (\"…\" while it reads, unless "
                  "wait)", query=True)
    cmds.register("rename_session", rename, {"old": REQUIRED, "new": REQUIRED},
                  "rename a recorded session (refused for the one being recorded); the control holder only; "
                  "returns the new name")
    cmds.register("delete_session", delete, {"name": REQUIRED},
                  "delete a recorded session and its journal (refused for the one being recorded); the control "
                  "holder only")
    cmds.register("reevaluate_session", reevaluate, {"name": REQUIRED, "new": REQUIRED, "tip_radius": 0.0,
                                                      "method": "recorded", "tolerances": None},
                  "recompute a session's hits and features from its raw counts with another tip radius (mm; 0: as "
                  "recorded) and fit method (" + ", ".join(REEVALUATE_METHODS) + ") into the new session new, in the "
                  "session worker; tolerances, in process: a DMIS run's re-evaluation (cmm.dmis.replay); the "
                  "control holder only; returns the counts and the features that could not be refitted")
    _register_trends(cmds, measurement)


def _register_trends(cmds: Any, measurement: Any) -> None:
    REQUIRED = cmds.REQUIRED  # noqa: N806

    def trends() -> Any:
        return getattr(measurement, "trends", None)

    def need() -> Any:
        t = trends()
        if t is None:
            from .trends import TrendError

            raise TrendError("this station records no trends: start it with cmm serve --trends DIR")
        return t

    def summary(client: Any) -> dict[str, Any] | None:  # cheap: a page asks it five times a second
        t = trends()
        if t is None:
            return None
        return {"version": t.version, "shared": bool(t.database_url), "directory": str(t.directory)}

    def series(client: Any) -> dict[str, Any]:
        t = need()
        return {"series": list(t.series()), "status": t.status_text()}

    def options(client: Any, series: str) -> dict[str, Any]:
        t = need()
        return {"characteristics": [[name, unit] for name, unit in t.characteristics(series)],
                "stations": list(t.stations(series))}

    def charts(client: Any, series: str) -> list[Any]:
        from .trends_chart import charts_for

        return charts_for(need(), series)

    cmds.register("trends", summary, {},
                  "None when the station records no trends; else a counter that grows with every part recorded "
                  "here (version), whether a shared database is configured (shared) and the trends folder "
                  "(directory)", query=True)
    cmds.register("trend_series", series, {},
                  "the series recorded (series: every station's in the shared database, else this station's) and "
                  "where the charts come from, in the operator's words (status)", query=True)
    cmds.register("trend_options", options, {"series": REQUIRED},
                  "a series' characteristics ([name, unit]) and the stations that recorded its parts", query=True)
    cmds.register("trend_history", lambda client, series, characteristic, station=None: need().history(
                      series, characteristic, station),
                  {"series": REQUIRED, "characteristic": REQUIRED, "station": None},
                  "one characteristic over a series' parts, in time order (cmm.session.trends.History: "
                  "values, nominals, limits, stations, serials; source: the shared database or this station's "
                  "journal); station: that station's parts only", query=True)
    cmds.register("trend_charts", charts, {"series": REQUIRED},
                  "in process: the control charts of every characteristic of a series, as the report includes "
                  "them", query=True)
