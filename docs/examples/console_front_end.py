"""A front end in about fifty lines: a console that follows the machine and moves it, given only the API.

Run it on the simulator:  python3 docs/examples/console_front_end.py
Every front end of the station (the page, the pendant, I++ DME, DMIS, OPC UA) has this shape: it receives the
command API, sends verbs as its client (``api.invoke``, the one call form), reads queries and subscribes to their change streams. It never sees
the station, the machine or the measurement model, and the API decides what its client may do.
"""

from __future__ import annotations

import threading
from typing import Any, Callable


def console(api: Any, client: str = "console", say: Callable[[str], None] = print) -> list[float]:
    """Take control, follow the tip while it moves 20 mm along X and back, give control up; returns the
    X positions heard on the way."""
    heard: list[float] = []
    still = threading.Event()

    def on_change(changed: dict) -> None:  # called from the API's own thread, at most 10 times a second
        if "position" in changed and changed["position"] is not None:
            x, y, z = changed["position"]
            heard.append(x)
            say(f"tip at X {x:9.3f}  Y {y:9.3f}  Z {z:9.3f} mm")
        if "state" in changed:
            still.set()

    try:
        api.invoke(client, "take_control")
    except Exception as exc:  # noqa: BLE001 - refusals come as one sentence for the operator
        say(f"cannot take control: {exc}")
        return heard
    with api.subscribe(client, {"position": {"frame": "machine"}, "state": None}, on_change, rate=10):
        x, y, z = api.invoke(client, "position", frame="machine")
        for target in ([x + 20.0, y, z], [x, y, z]):
            try:  # a motion verb returns its status; wait() gives its result or raises its error
                api.invoke(client, "move", target=target, frame="machine").wait(300)
                say("arrived")
            except Exception as exc:  # noqa: BLE001 - told in the operator's words
                say(f"refused: {exc}")
    api.invoke(client, "release_control")
    return heard


if __name__ == "__main__":
    from cmm.station import Station  # only the composition root knows the station; the front end gets the API

    station = Station(port="sim://?cmm=1&pace=1").start("console example", home=True)  # at the machine's pace
    try:
        console(station.controller.commands)
    finally:
        station.close()
