"""Cycle time: machine seconds per hit against the minimum-time bound of the same path.

    python benchmarks/bench_cycle_time.py [--points 8]

Runs on the simulated CMM (virtual clock, so the figures are machine time and do
not depend on how busy the computer is):

- auto-measure of the sample part's top plane, bore, boss and sphere (the plans
  the Measure tab makes: a feature's first hit over the clearance plane, the
  others straight or over the feature's hop height where the rails prove it free);
- an I++ DME sequence, GoTo over a point then PtMeas on it, as a commercial
  front end sends it;
- the program taught from the auto-measure session, run by the program runner
  (``run_program``, what the ``run_program`` command runs), its hits
  over the clearance height and hopping within each feature (machine s/hit and
  the as-run bound only).

Two bounds, each the time trapezoid profiles need (a triangle on short lines)
with a stop at every corner and no time between moves:

- **as run**: every straight line the machine ran (start, end where it really
  stopped, speed, acceleration). measured / this bound is the controller's
  overhead (link transactions, polling, settling) on the path it took;
- **best path**: the same hits on the best path the rails allow, whatever path
  ran: from where the tip was, a feature's first hit over the clearance plane,
  each later hit straight from the previous retract where the line is proven
  free of the part mesh, else over the feature's hop height where that is proven
  free, else over the clearance plane (the control core's ``probe_paths``); the
  approach to the contact at the configured probing speed and acceleration, the
  retract at the prober's retract speed. For the I++ sequence every hit, the
  first too, goes straight where proven (its GoTo moves are the client's own).
  measured / this bound is what the cycle costs over what the axes allow.

Target: <= 1.25x.
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
from cmm.measurement.plan import plan_at_pick, plan_targets, run_plan
from cmm.metrology.hops import hop_height
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


def path_bound(station: Station, targets, start) -> float:
    """The minimum time of the hits ``targets`` (as ``probe_paths`` takes them) from ``start`` on the path the
    rails allow: every rapid leg at the positioning speed and acceleration, the approach to the contact at the
    probing ones, the retract at the prober's retract speed (five times the probing speed)."""
    cfg = station.config
    fast = (cfg.speeds.positioning, cfg.accelerations.positioning)
    probing = (cfg.speeds.probing, cfg.accelerations.probing)
    total = 0.0
    for c in station.controller.probe_paths(targets, start=np.asarray(start, float)):
        corners = [c.start, *c.rapid]
        total += sum(trapezoid_time(float(np.linalg.norm(b - a)), *fast) for a, b in zip(corners[:-1], corners[1:]))
        total += trapezoid_time(float(np.linalg.norm(c.contact - c.pre)), *probing)
        total += trapezoid_time(float(np.linalg.norm(c.retract - c.contact)), 5 * probing[0], fast[1])
    return total


def report(label: str, hits: int, machine_s: float, bound_s: float, best_s: float) -> None:
    print(f"{label:38s} {hits:3d} hits  {machine_s / hits:5.2f} machine s/hit  "
          f"as-run bound {bound_s / hits:5.2f} s/hit (ratio {machine_s / bound_s:4.2f})  "
          f"best-path bound {best_s / hits:5.2f} s/hit (ratio {machine_s / best_s:4.2f})")


def auto_measure(station: Station, log: LineLog) -> None:
    model = station.measurement
    clock = station.machine.clock
    # (name, a ray in part coordinates that meets the feature's face first)
    features = [("top plane", (20.0, 10.0, 100.0), (0, 0, -1)), ("bore", (30.0, 40.0, 20.0), (1, 0, 0)),
                ("boss", (70.0, -20.0, 47.0), (0, 1, 0)), ("sphere", (73.0, 58.0, 100.0), (0, 0, -1))]
    total_t = total_b = total_p = 0.0
    total_n = 0
    for name, origin, direction in features:
        face = face_at(model, origin, direction)
        plan = plan_at_pick(model, face)
        best = path_bound(station, plan_targets(plan), station.machine.position)
        mark, t0 = log.mark(), clock.now()
        run_plan(model, plan, name=name)
        t, b = clock.now() - t0, log.bound_since(mark)
        report(f"auto-measure {name} ({plan.kind})", len(plan), t, b, best)
        total_t, total_b, total_p, total_n = total_t + t, total_b + b, total_p + best, total_n + len(plan)
    report("auto-measure, all four", total_n, total_t, total_b, total_p)


def ippdme_ptmeas(station: Station, log: LineLog, points: int) -> None:
    server = IppServer(StationBackend(station.controller.commands), "127.0.0.1", 0).start()
    clock = station.machine.clock
    try:
        with IppClient("127.0.0.1", server.port) as c:
            for cmd in ("StartSession()", 'ChangeTool("Probe1")', "SetProp(Tool.GoToPar.Speed(50))"):
                assert c.call(cmd).ok, cmd
            pose = station.measurement.part.pose
            top = (pose @ np.array([10.0, 15.0, 40.0, 1.0]))[:3]
            assert c.call(f"GoTo(Z({top[2] + 30:.3f}))").ok
            hits = [(pose @ np.array([10.0 + 5.0 * k, 12.0 + 6.0 * (k % 2), 40.0, 1.0]))[:3] for k in range(points)]
            down = np.array([0.0, 0.0, -1.0])  # PtMeas IJK(0, 0, 1): the surface normal, machine axes
            hop = hop_height(station.measurement.part.mesh, pose, hits, station.controller.tip_radius)
            best = path_bound(station, [(p, down, None, hop) for p in hits], station.machine.position)
            mark, t0 = log.mark(), clock.now()
            for p in hits:
                g = c.call(f"GoTo(X({p[0]:.3f}), Y({p[1]:.3f}), Z({p[2] + 10:.3f}))")
                assert g.ok, g.responses
                t = c.call(f"PtMeas(X({p[0]:.3f}), Y({p[1]:.3f}), Z({p[2]:.3f}), IJK(0, 0, 1))")
                assert t.ok, t.responses
            report("I++ GoTo + PtMeas on the top face", points, clock.now() - t0, log.bound_since(mark), best)
            c.call("EndSession()")
    finally:
        server.close()


def program_run(station: Station, log: LineLog) -> None:
    from cmm.measurement.program import run_program
    from cmm.program.toml_program import teach
    from cmm.journal.store import open_session

    model, clock = station.measurement, station.machine.clock
    program = teach(open_session(model.journal.path), name="cycle time", part_mesh=model.part.mesh,
                    part_nominals=model.part.nominal_features)
    for hops in (False, True):
        mark, t0 = log.mark(), clock.now()
        station.controller.run_job(None, "program", lambda: run_program(program, model, hops=hops))
        t, b, n = clock.now() - t0, log.bound_since(mark), len(program.hits)
        print(f"{'program, ' + ('hops' if hops else 'over the clearance'):38s} {n:3d} hits  {t / n:5.2f} machine s/hit  "
              f"as-run bound {b / n:5.2f} s/hit (ratio {t / b:4.2f})")


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
            program_run(station, log)  # from the auto-measure session (the I++ one opens a session of its own)
            ippdme_ptmeas(station, log, args.points)
        finally:
            station.close()


if __name__ == "__main__":
    main()
