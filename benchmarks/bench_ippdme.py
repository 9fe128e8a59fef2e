"""I++ DME server figures: transaction round trips over TCP and PtMeas cycles on the simulated station.

    python benchmarks/bench_ippdme.py [--n 500] [--points 10]

Round trips: a query answered from the server's state (IsHomed), one that
reads the machine (Get(X(), Y(), Z())) and a fast-queue one (GetErrStatusE),
each sent after the previous one completed, as NIST's client does. PtMeas:
points on the sample part's top face on the virtual clock (machine seconds
per point, and wall seconds per point, which is how fast a test runs).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time

import numpy as np

from cmm.ippdme.backend import StationBackend
from cmm.ippdme.client import IppClient
from cmm.ippdme.server import IppServer
from cmm.station import Station


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=500, help="round trips per query")
    ap.add_argument("--points", type=int, default=10, help="PtMeas cycles")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        station = Station(port="sim://?cmm=1", session_dir=tmp).start()
        server = IppServer(StationBackend(station.controller.commands), "127.0.0.1", 0).start()
        try:
            with IppClient("127.0.0.1", server.port) as c:
                for cmd in ("StartSession()", "Home()", 'ChangeTool("Probe1")', "SetProp(Tool.GoToPar.Speed(50))"):
                    assert c.call(cmd).ok, cmd
                for cmd in ("IsHomed()", "Get(X(), Y(), Z())", "GetErrStatusE()"):
                    times = []
                    for _ in range(args.n):
                        t = time.perf_counter()
                        c.call(cmd)
                        times.append(time.perf_counter() - t)
                    times.sort()
                    print(f"{cmd:22s} round trip p50 {statistics.median(times) * 1e3:.2f} ms, "
                          f"p99 {times[int(0.99 * len(times)) - 1] * 1e3:.2f} ms, {len(times) / sum(times):.0f}/s")
                pose = station.measurement.part.pose
                assert c.call("GoTo(Z(70))").ok
                wall, machine = time.perf_counter(), station.machine.clock.now()
                for k in range(args.points):
                    p = (pose @ np.array([10.0 + 5 * k, 15.0, 40.0, 1.0]))[:3]
                    assert c.call(f"GoTo(X({p[0]:.3f}), Y({p[1]:.3f}))").ok
                    t = c.call(f"PtMeas(X({p[0]:.3f}), Y({p[1]:.3f}), Z({p[2]:.3f}), IJK(0, 0, 1))")
                    assert t.ok, t.responses
                wall, machine = time.perf_counter() - wall, station.machine.clock.now() - machine
                print(f"PtMeas (with a GoTo to each point): {machine / args.points:.2f} machine s/point, "
                      f"{wall / args.points:.3f} wall s/point on the virtual clock ({machine / wall:.0f}x)")
                c.call("EndSession()")
        finally:
            server.close()
            station.close()


if __name__ == "__main__":
    main()
