"""Machine events in an operator's words: for toasts, the journal and the report.

The machine layer emits ``(kind, info)`` with ``info`` a dict of values
(``contact {'position': [...]}``); an operator should read "Unexpected probe
contact at X 201.334 Y 150.020 Z 38.115: the machine stopped". Older journals
recorded ``str(info)``; :func:`error_text` words those too.
"""

from __future__ import annotations

import ast
from collections import Counter
from typing import Any

TITLES = {"contact": "Unexpected probe contact", "deadman": "Jog stopped", "limit": "End of travel",
          "error": "Machine error", "estop": "Emergency stop", "fault": "Machine fault", "homed": "Homed",
          "reset": "Reset", "reconnect": "Reconnected", "stop": "STOP not confirmed"}


def _xyz(v: Any) -> str:
    try:
        x, y, z = (float(c) for c in v)
    except (TypeError, ValueError):
        return str(v)
    return f"X {x:.3f} Y {y:.3f} Z {z:.3f}"


def event_title(kind: str) -> str:
    return TITLES.get(kind, kind.replace("_", " ").capitalize())


def event_text(kind: str, info: Any = None) -> str:
    """One sentence for a machine event."""
    d = info if isinstance(info, dict) else {}
    if kind == "contact":
        where = f" at {_xyz(d['position'])}" if "position" in d else ""
        return f"Unexpected probe contact{where}: the machine stopped and recorded no hit."
    if kind == "deadman":
        return "The jog stopped: the browser stopped refreshing it (dead-man)."
    if kind == "limit":
        return f"The jog stopped at the end of travel of the {str(d.get('axis', '?')).upper()} axis."
    if kind == "estop" and not d.get("message"):
        return "Emergency stop: amplifiers off. Reset re-enables the servos."
    message = d.get("message") or d.get("reason") or (info if isinstance(info, str) else "")
    if message:
        return str(message)
    if d:
        return "; ".join(f"{k.replace('_', ' ')} {v}" for k, v in d.items())
    return event_title(kind)


def error_text(source: str, message: str) -> str:
    """A journal ``error`` event (``source``, ``message``) as a sentence."""
    kind = source.split(":", 1)[1] if source.startswith("machine:") else ""
    info: Any = message
    if message.startswith("{") and message.endswith("}"):
        try:
            info = ast.literal_eval(message)
        except (ValueError, SyntaxError):
            info = message
    if kind:
        return event_text(kind, info)
    return message if isinstance(info, str) else event_text("error", info)


def grouped(texts: list[str]) -> list[tuple[str, int]]:
    """Repeated sentences once each with their count, in order of first appearance."""
    counts = Counter(texts)
    seen: dict[str, None] = {}
    for t in texts:
        seen.setdefault(t, None)
    return [(t, counts[t]) for t in seen]
