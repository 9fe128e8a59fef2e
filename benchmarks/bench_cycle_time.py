"""Cycle time: machine seconds per hit against the minimum-time bound of the same path.

    python benchmarks/bench_cycle_time.py [--points 8]

Runs on the simulated CMM (virtual clock, so the figures are machine time and do
not depend on how busy the computer is):

- auto-measure of the sample part's top plane, bore, boss and sphere (the plans
  the Measure tab makes: each hit over the clearance plane);
- an I++ DME sequence, GoTo over a point then PtMeas on it, as a commercial
  front end sends it.

Every straight line the machine runs is recorded (start, end where it really
stopped, speed, acceleration). The bound is the sum, over those lines, of the
time a trapezoid profile needs with the configured speed and acceleration
(a triangle on short lines): what the axes allow on this path with a stop at
every corner and no time between moves. The ratio measured / bound is the
overhead of the controller (link transactions, polling, settling); target
<= 1.25.
"""

from __future__ import annotations

import argparse
import math
import tempfile
from dataclasses import dataclass

import numpy as np

from cmm.ippdme.backend import StationBackend
from cmm.ippdme.client import IppClient
from cmm.ippdme.server import IppServer
from cmm.measurement.plan import plan_at_pick, run_plan
from cmm.sim.cmm_sim import TRUE_PART_POSE
from cmm.station import Station


def trapezoid_time(distance: float, speed: float, accel: float) -> float:
    """Shortest time over ``distance`` from rest to rest with |v| <= speed and |a| <= accel."""
    if distance <= 0:
        return 0.0
    if distance >= speed * speed / accel:
        return distance / speed + speed / accel
    return 2.0 * math.sqrt(distance / accel)


@dataclass
class Line:
    start: np.ndarray
    speed: float
    accel: float
    end: np.ndarray | None = None

    @property
    def bound(self) -> float:
        end = self.start if self.end is None else self.end
        return trapezoid_time(float(np.linalg.norm(end - self.start)), self.speed, self.accel)


class LineLog:
    """Records every straight line the machine starts, and where it really ended (a probing move stops at the
    trigger, not at its programmed end)."""

    def __init__(self, machine) -> None:
        self.machine = machine
        self.lines: list[Line] = []
        original = machine._start_line

        def start_line(motion, target, speed, accel):
            line = Line(machine.position.copy(), float(speed), float(accel))
            self.lines.append(line)
            status = original(motion, target, speed, accel)
            status.add_callback(lambda _s: setattr(line, "end", machine.position.copy()))
            return status

        machine._start_line = start_line  # the benchmark's own instrumentation, never done by the station

    def mark(self) -> int:
        return len(self.lines)

    def bound_since(self, mark: int) -> float:
        return sum(line.bound for line in self.lines[mark:])


def face_at(model, origin, direction) -> int:
    """The part face a ray (part coordinates) meets first."""
    pose = model.part.pose
    picked = model.pick((pose @ np.array([*origin, 1.0]))[:3], pose[:3, :3] @ np.asarray(direction, float))
    if picked is None:
        raise SystemExit(f"the ray from {origin} along {direction} misses the sample part")
    return picked[0].face_id


def report(label: str, hits: int, machine_s: float, bound_s: float) -> None:
    print(f"{label:38s} {hits:3d} hits  {machine_s / hits:5.2f} machine s/hit  bound {bound_s / hits:5.2f} s/hit  "
          f"ratio {machine_s / bound_s:4.2f}")


def auto_measure(station: Station, log: LineLog) -> None:
    model = station.measurement
    clock = station.machine.clock
    # (name, a ray in part coordinates that meets the feature's face first)
    features = [("top plane", (20.0, 10.0, 100.0), (0, 0, -1)), ("bore", (30.0, 40.0, 20.0), (1, 0, 0)),
                ("boss", (70.0, -20.0, 47.0), (0, 1, 0)), ("sphere", (73.0, 58.0, 100.0), (0, 0, -1))]
    total_t = total_b = 0.0
    total_n = 0
    for name, origin, direction in features:
        face = face_at(model, origin, direction)
        plan = plan_at_pick(model, face)
        mark, t0 = log.mark(), clock.now()
        run_plan(model, plan, name=name)
        t, b = clock.now() - t0, log.bound_since(mark)
        report(f"auto-measure {name} ({plan.kind})", len(plan), t, b)
        total_t, total_b, total_n = total_t + t, total_b + b, total_n + len(plan)
    report("auto-measure, all four", total_n, total_t, total_b)


def ippdme_ptmeas(station: Station, log: LineLog, points: int) -> None:
    server = IppServer(StationBackend(station), "127.0.0.1", 0).start()
    clock = station.machine.clock
    try:
        with IppClient("127.0.0.1", server.port) as c:
            for cmd in ("StartSession()", 'ChangeTool("Probe1")', "SetProp(Tool.GoToPar.Speed(50))"):
                assert c.call(cmd).ok, cmd
            pose = station.measurement.part.pose
            top = (pose @ np.array([10.0, 15.0, 40.0, 1.0]))[:3]
            assert c.call(f"GoTo(Z({top[2] + 30:.3f}))").ok
            mark, t0 = log.mark(), clock.now()
            for k in range(points):
                p = (pose @ np.array([10.0 + 5.0 * k, 12.0 + 6.0 * (k % 2), 40.0, 1.0]))[:3]
                g = c.call(f"GoTo(X({p[0]:.3f}), Y({p[1]:.3f}), Z({p[2] + 10:.3f}))")
                assert g.ok, g.responses
                t = c.call(f"PtMeas(X({p[0]:.3f}), Y({p[1]:.3f}), Z({p[2]:.3f}), IJK(0, 0, 1))")
                assert t.ok, t.responses
            report("I++ GoTo + PtMeas on the top face", points, clock.now() - t0, log.bound_since(mark))
            c.call("EndSession()")
    finally:
        server.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=8, help="I++ PtMeas cycles")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        station = Station(port="sim://?cmm=1", session_dir=tmp).start("cycle time", home=True)
        try:
            cfg = station.config
            print(f"speeds: positioning {cfg.speeds.positioning:g} mm/s, probing {cfg.speeds.probing:g} mm/s; "
                  f"accelerations {cfg.accelerations.positioning:g} / {cfg.accelerations.probing:g} mm/s^2; "
                  f"approach {cfg.probe.approach_distance:g} mm, search {cfg.probe.search_distance:g} mm, "
                  f"retract {cfg.probe.retract_distance:g} mm")
            station.measurement.set_alignment(TRUE_PART_POSE, "manual", note="the simulator's true set-up")
            log = LineLog(station.machine)
            auto_measure(station, log)
            ippdme_ptmeas(station, log, args.points)
        finally:
            station.close()


if __name__ == "__main__":
    main()
