"""OPC UA server figures on the simulated station: start-up, read round trips, and the position's notifications
during a long move against the server's bounded update rate.

    python benchmarks/bench_opcua.py [--rate 10] [--reads 200] [--seconds 10]

The station runs the simulated CMM in real time (sim://?cmm=1&clock=realtime) so the move lasts wall seconds;
a client subscribes to the tip position's X with a 0 ms publishing interval (as fast as the server offers) and
counts the changes it receives while the machine travels: at most ``rate`` a second whatever the machine does.
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import sys
import tempfile
import time
from pathlib import Path

from asyncua import Client

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from ippdme_support import nist_config  # noqa: E402
from netutil import free_port  # noqa: E402

from cmm.control.access import Control  # noqa: E402
from cmm.opcua import model  # noqa: E402
from cmm.opcua.server import OpcUaServer  # noqa: E402
from cmm.station import Station  # noqa: E402


async def measure(server: OpcUaServer, station: Station, reads: int, seconds: float) -> dict:
    out = {}
    async with Client(server.url, timeout=60) as client:
        ns = await client.get_namespace_array()
        machines = await client.nodes.objects.get_child([f"{ns.index(model.MACHINERY)}:Machines"])
        (gms,) = await machines.get_children()
        mt, st = ns.index(model.MACHINE_TOOL), ns.index(model.STATION)
        x = await gms.get_child([f"{mt}:Monitoring", f"{st}:Axes", f"{st}:Position", "0:X"])
        times = []
        for _ in range(reads):
            t0 = time.perf_counter()
            await x.read_value()
            times.append(time.perf_counter() - t0)
        out["read_ms"] = (statistics.median(times) * 1e3, sorted(times)[int(0.95 * len(times)) - 1] * 1e3)
        seen: list[tuple[float, float]] = []

        class Handler:
            def datachange_notification(self, node, value, data):
                seen.append((time.monotonic(), float(value)))

        sub = await client.create_subscription(0, Handler())
        await sub.subscribe_data_change(x, sampling_interval=0)
        api = station.controller.commands
        start = api.invoke(None, "position")
        speed = 30.0
        target = [float(start[0]) + speed * seconds, float(start[1]), float(start[2])]
        status = api.invoke(None, "move", target=target, frame="machine", path="straight", speed=speed)
        t0 = time.monotonic()
        await asyncio.get_running_loop().run_in_executor(None, status.wait, seconds * 4 + 30)
        elapsed = time.monotonic() - t0
        moving = [v for t, v in seen if t >= t0]
        out["notifications"] = len(moving)
        out["per_second"] = len(moving) / elapsed
        out["move_s"] = elapsed
        await sub.delete()
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=float, default=10.0, help="the server's update rate, Hz")
    parser.add_argument("--reads", type=int, default=200)
    parser.add_argument("--seconds", type=float, default=10.0, help="length of the move, s")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        station = Station(nist_config(), port="sim://?cmm=1&clock=realtime", session_dir=Path(tmp) / "s")
        station.controller.use_policy_of(Control())
        station.start()
        t0 = time.monotonic()
        server = OpcUaServer(station.controller.commands, "127.0.0.1", free_port(), rate=args.rate).start()
        start_s = time.monotonic() - t0
        try:
            figures = asyncio.run(measure(server, station, args.reads, args.seconds))
        finally:
            server.close()
            station.close()
    print(f"OPC UA server start-up (asyncua's base address space + the GMS model): {start_s:.1f} s")
    print(f"read of the position's X: median {figures['read_ms'][0]:.2f} ms, p95 {figures['read_ms'][1]:.2f} ms")
    print(f"position notifications during a {figures['move_s']:.1f} s move: {figures['notifications']} "
          f"({figures['per_second']:.1f}/s; the server's rate {args.rate:g}/s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
