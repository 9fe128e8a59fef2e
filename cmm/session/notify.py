"""A job ends, people know: notifications of a run's end, a machine fault and an out-of-tolerance result, to a
webhook URL (an HTTP POST of JSON) and over MQTT (paho-mqtt), both optional.

Every message is one JSON object::

    {"event": "run_end" | "out_of_tolerance" | "fault", "station": ..., "part": ..., "program": ...,
     "session": ..., "verdict": "PASS" | "FAIL" | "INCOMPLETE" | "DONE" | "STOPPED" | "FAULT",
     "failed": [characteristic names],
     "characteristics": n, "report": link, "message": one sentence, "time": ISO 8601}

Every run sends ``run_end``: a routine, a DMIS program (``cmm run`` or the page), a TOML program. Its verdict: FAIL
when a characteristic is out of tolerance, INCOMPLETE when one could not be judged (no nominal or tolerance),
PASS when all are in, DONE for a run without characteristics, STOPPED for a run that ended early (an error, a
cancel, a machine fault: the reason in the message). A run that ends with a characteristic out of tolerance sends
``run_end`` and then ``out_of_tolerance``. Over MQTT
the topic is ``<prefix>/<station>/<event>`` (prefix ``cmm`` unless the URL names one: ``mqtt://host:1883/shop/cmm``),
QoS 1. The report link: ``report_url`` with ``{session}``, ``{program}`` and ``{station}`` filled in, else the
``file://`` URI of the report the Report tab writes (``<sessions>/<session>-report.html``).

Sending happens in a background thread with a queue: a run, a hit or a fault never waits for the network. A
failed send is retried (three tries, 1 s and 2 s apart), then dropped with the reason in :attr:`Notifier.errors`
(and the station's log); the measurement is never affected.

Configuration: the station's TOML configuration, section ``[notify]`` (``webhook``, ``mqtt``, ``report_url``,
``events``: a list of the events to send, default all three, ``station``), and the command line flags
``--notify-webhook URL``, ``--notify-mqtt URL``, ``--report-url TEMPLATE`` of ``cmm serve`` and ``cmm run``
(the flags win).
"""

from __future__ import annotations

import json
import queue
import socket
import threading
import time
import tomllib
import urllib.error
import urllib.parse
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

EVENTS = ("run_end", "out_of_tolerance", "fault")
FAULT_KINDS = ("fault", "estop", "error", "contact")  # the machine events that are faults (the model's errors)


class NotifyError(ValueError):
    """A notification setting that cannot be used, in words."""


@dataclass
class NotifyConfig:
    webhook: str = ""
    mqtt: str = ""
    report_url: str = ""
    events: tuple[str, ...] = EVENTS
    station: str = ""
    timeout: float = 5.0

    @property
    def enabled(self) -> bool:
        return bool(self.webhook or self.mqtt)

    def check(self) -> "NotifyConfig":
        if self.webhook and urllib.parse.urlsplit(self.webhook).scheme not in ("http", "https"):
            raise NotifyError(f"the webhook {self.webhook!r} is not an http:// or https:// URL")
        if self.mqtt:
            u = urllib.parse.urlsplit(self.mqtt)
            if u.scheme not in ("mqtt", "tcp") or not u.hostname:
                raise NotifyError(f"the MQTT broker {self.mqtt!r} is not an mqtt://host[:port][/topic prefix] URL")
        unknown = [e for e in self.events if e not in EVENTS]
        if unknown:
            raise NotifyError(f"unknown notification event {unknown[0]!r}: choose from {', '.join(EVENTS)}")
        return self


def load_config(path: str | Path | None, *, webhook: str | None = None, mqtt: str | None = None,
                report_url: str | None = None, station: str | None = None) -> NotifyConfig:
    """The ``[notify]`` section of the station's TOML configuration (if any), with the command line's values
    over it."""
    section: dict[str, Any] = {}
    if path:
        try:
            section = tomllib.loads(Path(path).read_text()).get("notify", {}) or {}
        except (OSError, tomllib.TOMLDecodeError) as exc:
            raise NotifyError(f"cannot read the [notify] settings of {path}: {exc}") from None
        if not isinstance(section, dict):
            raise NotifyError(f"{path}: [notify] must be a table")
        unknown = sorted(set(section) - {"webhook", "mqtt", "report_url", "events", "station", "timeout"})
        if unknown:
            raise NotifyError(f"{path}: [notify] {unknown[0]} is not a known setting")
    cfg = NotifyConfig(webhook=str(webhook or section.get("webhook") or ""),
                       mqtt=str(mqtt or section.get("mqtt") or ""),
                       report_url=str(report_url or section.get("report_url") or ""),
                       events=tuple(section.get("events") or EVENTS),
                       station=str(station or section.get("station") or ""),
                       timeout=float(section.get("timeout", 5.0)))
    return cfg.check()


def add_arguments(p: Any) -> None:
    """The command line flags (``cmm serve``, ``cmm run``)."""
    p.add_argument("--notify-webhook", metavar="URL", help="POST a JSON message to URL when a run ends, a result is "
                   "out of tolerance or the machine faults (also [notify] webhook in the --config TOML)")
    p.add_argument("--notify-mqtt", metavar="URL", help="publish the same messages to an MQTT broker, "
                   "mqtt://host[:port][/topic prefix] (topic <prefix>/<station>/<event>; default prefix cmm)")
    p.add_argument("--report-url", metavar="TEMPLATE", help="the report link in the messages, with {session}, "
                   "{program}, {station} (default: the file:// URI of the session's report)")


@dataclass
class Notifier:
    """Sends the station's notifications in the background (see the module docstring)."""

    config: NotifyConfig
    session_dir: Any = None  # where the Report tab writes <session>-report.html (the default link)
    sent: int = 0
    errors: list[str] = field(default_factory=list)
    log: Any = None  # fn(kind, message): the operator's event log

    def __post_init__(self) -> None:
        self.config.check()
        self.station = self.config.station or socket.gethostname()
        self._queue: queue.Queue = queue.Queue()
        self._mqtt: Any = None
        self._idle = threading.Condition()
        self._busy = 0
        self._thread = threading.Thread(target=self._loop, name="notify", daemon=True)
        self._thread.start()

    # --- what happens ----------------------------------------------------------------------------

    def attach(self, model: Any) -> "Notifier":
        """Send faults of this measurement model's machine (its listeners) and its runs' ends (record_trend)."""
        model.notifier = self
        self.session_dir = self.session_dir or getattr(model, "session_dir", None)
        model.subscribe(lambda kind, info: self.fault(model, kind, info) if kind in FAULT_KINDS else None)
        return self

    def run_end(self, model: Any, program: str, values: Iterable[Any], serial: str = "") -> None:
        """A run of ``program`` ended with these characteristic ``values`` (:class:`cmm.session.trends.Measured`:
        ``name``, ``ok``)."""
        values = list(values)
        failed = [v.name for v in values if v.ok is False]
        missing = sum(v.ok is None for v in values)
        verdict = "FAIL" if failed else ("INCOMPLETE" if missing else ("PASS" if values else "DONE"))
        base = self._base(model, program, serial)
        text = (f"{program} on {base['part']}: {verdict}, {len(values)} characteristics"
                + (f", {len(failed)} out of tolerance ({', '.join(failed[:5])}{', ...' if len(failed) > 5 else ''})"
                   if failed else ""))
        self.send({**base, "event": "run_end", "verdict": verdict, "failed": failed, "characteristics": len(values),
                   "message": text})
        if failed:
            self.send({**base, "event": "out_of_tolerance", "verdict": "FAIL", "failed": failed,
                       "characteristics": len(values), "message": text})

    def run_stopped(self, model: Any, program: str, reason: Any, serial: str = "") -> None:
        """A run of ``program`` ended before its end (an error, a cancel, a fault): ``run_end``, verdict STOPPED."""
        base = self._base(model, program, serial)
        why = " ".join(str(reason).split()) or type(reason).__name__
        self.send({**base, "event": "run_end", "verdict": "STOPPED", "failed": [], "characteristics": 0,
                   "message": f"{program} on {base['part']}: STOPPED, {why}"})

    def fault(self, model: Any, kind: str, info: Any) -> None:
        from ..journal.wording import event_text

        try:
            text = event_text(kind, info)
        except Exception:  # noqa: BLE001 - a message that cannot be worded is sent as it came
            text = f"{kind}: {info}"
        base = self._base(model, "", "")
        self.send({**base, "event": "fault", "verdict": "FAULT", "failed": [], "characteristics": 0,
                   "message": f"machine {kind} on {self.station}: {text}"})

    def _base(self, model: Any, program: str, serial: str) -> dict[str, Any]:
        journal = getattr(model, "journal", None)
        session = ""
        if journal is not None:
            session = str(getattr(journal, "name", "") or Path(str(getattr(journal, "path", ""))).stem)
        part = getattr(model, "part", None)
        part_name = getattr(part, "name", None) or str((getattr(model, "info", {}) or {}).get("part_number") or "")
        return {"station": self.station, "part": part_name or "no part", "serial": serial, "program": program,
                "session": session, "report": self.report_link(session, program),
                "time": time.strftime("%Y-%m-%dT%H:%M:%S%z")}

    def report_link(self, session: str, program: str = "") -> str:
        if self.config.report_url:
            return self.config.report_url.format(session=urllib.parse.quote(session),
                                                 program=urllib.parse.quote(program),
                                                 station=urllib.parse.quote(self.station))
        d = self.session_dir
        if d is None or str(d).startswith(("postgresql://", "postgres://")):
            d = "exports"  # the Report tab's folder for a database store
        return (Path(d).resolve() / f"{session}-report.html").as_uri() if session else ""

    # --- sending ---------------------------------------------------------------------------------

    def send(self, message: dict[str, Any]) -> None:
        if message.get("event") not in self.config.events or not self.config.enabled:
            return
        with self._idle:
            self._busy += 1
        self._queue.put(message)

    def wait(self, timeout: float = 10.0) -> bool:
        """Wait until every queued message was sent or dropped (a real-time wait: real servers)."""
        end = time.monotonic() + timeout
        with self._idle:
            while self._busy:
                left = end - time.monotonic()
                if left <= 0:
                    return False
                self._idle.wait(left)
            return True

    def _loop(self) -> None:
        while True:
            message = self._queue.get()
            if message is None:
                break
            try:
                for target, fn in (("webhook", self._post), ("MQTT", self._publish)):
                    if (target == "webhook" and not self.config.webhook) or (target == "MQTT" and not self.config.mqtt):
                        continue
                    for attempt in range(3):
                        try:
                            fn(message)
                            self.sent += 1
                            break
                        except Exception as exc:  # noqa: BLE001 - the network's errors, in words
                            if attempt == 2:
                                why = (f"the {message['event']} notification could not be sent to the {target} "
                                       f"({' '.join(str(exc).split()) or type(exc).__name__})")
                                self.errors.append(why)
                                if self.log is not None:
                                    try:
                                        self.log("error", why)
                                    except Exception:  # noqa: BLE001
                                        pass
                            else:
                                time.sleep(1.0 * (attempt + 1))
            finally:
                with self._idle:
                    self._busy -= 1
                    self._idle.notify_all()

    def _post(self, message: dict[str, Any]) -> None:
        body = json.dumps(message).encode("utf-8")
        req = urllib.request.Request(self.config.webhook, data=body, method="POST",
                                     headers={"Content-Type": "application/json", "User-Agent": "cmm-station"})
        with urllib.request.urlopen(req, timeout=self.config.timeout) as resp:
            if resp.status >= 300:
                raise OSError(f"HTTP {resp.status}")

    def _topic(self, event: str) -> str:
        prefix = urllib.parse.urlsplit(self.config.mqtt).path.strip("/") or "cmm"
        station = "".join(c if c.isalnum() or c in "-_." else "_" for c in self.station)
        return f"{prefix}/{station}/{event}"

    def _publish(self, message: dict[str, Any]) -> None:
        import paho.mqtt.client as mqtt

        if self._mqtt is None:
            u = urllib.parse.urlsplit(self.config.mqtt)
            client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"cmm-{self.station}-{id(self):x}")
            if u.username:
                client.username_pw_set(urllib.parse.unquote(u.username), urllib.parse.unquote(u.password or ""))
            rc = client.connect(u.hostname, u.port or 1883, keepalive=30)
            if rc != 0:
                raise OSError(f"the broker refused the connection (code {rc})")
            client.loop_start()
            self._mqtt = client
        info = self._mqtt.publish(self._topic(message["event"]), json.dumps(message), qos=1)
        info.wait_for_publish(timeout=self.config.timeout)
        if not info.is_published():
            self._drop_mqtt()
            raise OSError(f"the broker did not acknowledge within {self.config.timeout:g} s")

    def _drop_mqtt(self) -> None:
        if self._mqtt is not None:
            try:
                self._mqtt.loop_stop()
                self._mqtt.disconnect()
            except Exception:  # noqa: BLE001
                pass
        self._mqtt = None

    def close(self, timeout: float = 10.0) -> None:
        """Send what waits (up to ``timeout``), then stop."""
        self.wait(timeout)
        self._queue.put(None)
        self._thread.join(timeout=2)
        self._drop_mqtt()


def from_args(args: Any, session_dir: Any = None) -> Notifier | None:
    """The notifier the command line and the --config TOML ask for, or None."""
    cfg = load_config(getattr(args, "config", None), webhook=getattr(args, "notify_webhook", None),
                      mqtt=getattr(args, "notify_mqtt", None), report_url=getattr(args, "report_url", None),
                      station=getattr(args, "station", None))
    return Notifier(cfg, session_dir=session_dir) if cfg.enabled else None
