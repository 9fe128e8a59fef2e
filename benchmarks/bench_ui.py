"""Browser station rates: probe-node updates the scene pushes, and the station's state sample rate.

Starts a Station on the simulator and the viser app on a free loopback port,
connects one WebSocket client (so updates really go out), moves the machine
for about five seconds, and prints:
  - machine state samples per second (the poll thread),
  - probe-node position updates per second pushed to the scene (the
    throttled updater, at most 25/s, only while the probe moves),
  - bytes per second the client received.

    python benchmarks/bench_ui.py [--seconds 5]
"""

from __future__ import annotations

import argparse
import socket
import tempfile
import threading
import time

import msgspec
import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    args = parser.parse_args()

    import viser
    from viser import _messages
    from websockets.sync.client import connect

    from cmm.station import Station
    from cmm.ui.app import StationApp

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    station = Station(session_dir=tempfile.mkdtemp()).start(home=True)
    app = StationApp(station.controller.commands, host="127.0.0.1", port=port, pendant=False)
    received = [0]
    stop = threading.Event()

    def client() -> None:
        with connect(f"ws://127.0.0.1:{port}", subprotocols=[f"viser-v{viser.__version__}"],
                     max_size=None) as ws:
            cam = _messages.ViewerCameraMessage((1.0, 0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 1.0, 0.01, 100.0, 600, 800,
                                                (0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
            ws.send(msgspec.msgpack.encode(cam.as_serializable_dict()))
            while not stop.is_set():
                try:
                    msg = ws.recv(timeout=0.1)
                    received[0] += len(msg)
                except TimeoutError:
                    pass

    t = threading.Thread(target=client, daemon=True)
    t.start()
    time.sleep(1.0)
    try:
        capp = app.add_client(client_id="bench", is_local=True)
        capp.take_control()
        # a long move so the probe keeps moving for the whole window
        start = station.machine.state.position
        target = start + np.array([200.0, 150.0, -150.0])
        status = capp.go_to(*target)
        time.sleep(0.3)
        s0, p0, k0, b0, t0 = station.machine.samples, app.updater.pushes, app.updater.ticks, received[0], time.monotonic()
        time.sleep(args.seconds)
        s1, p1, k1, b1, t1 = station.machine.samples, app.updater.pushes, app.updater.ticks, received[0], time.monotonic()
        dt = t1 - t0
        moving = status is not None and not status.done
        print(f"window                  {dt:.2f} s (machine still moving at the end: {moving})")
        print(f"station state samples   {(s1 - s0) / dt:8.1f} /s")
        print(f"probe updater ticks     {(k1 - k0) / dt:8.1f} /s")
        print(f"probe node updates      {(p1 - p0) / dt:8.1f} /s pushed to the scene")
        print(f"client received         {(b1 - b0) / dt / 1000:8.1f} kB/s over the WebSocket")
        capp.stop()
    finally:
        stop.set()
        t.join(timeout=2)
        app.close()
        station.close()


if __name__ == "__main__":
    main()
