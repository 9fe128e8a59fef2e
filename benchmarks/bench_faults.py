"""Link faults: N injected faults through a TCP fault proxy in front of the served simulator.

    python benchmarks/bench_faults.py --faults 1000 --kinds stall      # stalled replies only
    python benchmarks/bench_faults.py --faults 300                      # every kind

The simulator is served over TCP in this process (the code ``cmm sim --tcp``
runs), so each module's trajectory starts can be counted; ``--target
HOST:PORT`` puts the proxy in front of an external ``cmm sim --tcp`` instead
(doubled moves are then not counted). The three modules are parked in
position bands far apart, so any reply taken for another module shows.

For every fault, one operation runs through it (three polls of every axis, a
coordinated group move, or a velocity jog and its stop) and is classified:
- recovered: the operation completed and every reading was right;
- clear error: the bus raised LinkError / NmcError (then the benchmark, like
  an operator, reconnects and checks the state);
- wrong state: a reading from another module's band, a move that reported
  done away from its goal, or a position off after recovery;
plus doubled moves (a module started one commanded position move twice) and hangs (an
operation that took longer than --hang seconds).
"""

from __future__ import annotations

import argparse
import random
import statistics
import time
from collections import Counter, defaultdict

from cmm.nmc import codec
from cmm.nmc.bus import Bus, NmcError
from cmm.nmc.faults import Fault, FaultProxy
from cmm.nmc.module import Module
from cmm.sim.network import SimNetwork
from cmm.sim.plant import DEFAULT_GAINS
from cmm.sim.serve import serve_tcp

BANDS = {1: (0, 20_000), 2: (60_000, 80_000), 3: (-80_000, -60_000)}  # counts; 40,000 apart
VEL = codec.velocity_to_fixed(50, 500)
ACC = codec.acceleration_to_fixed(1000, 500)
JOG = codec.velocity_to_fixed(10, 500)
GROUP = 0x80


def make_fault(kind: str, rng: random.Random) -> Fault:
    if kind == "stall":
        return Fault("stall", rng.choice(("rx", "tx", "both")), duration=rng.uniform(0.05, 0.5))
    if kind == "blackout":
        return Fault("blackout", "both", duration=rng.uniform(0.1, 1.5))
    if kind == "disconnect":
        return Fault("disconnect")
    return Fault(kind, rng.choice(("rx", "tx")), count=rng.randint(1, 8 if kind == "garbage" else 3))


class Bench:
    def __init__(self, bus: Bus, proxy: FaultProxy, net: SimNetwork | None, rng: random.Random) -> None:
        self.bus, self.proxy, self.net, self.rng = bus, proxy, net, rng
        self.mods = [Module(bus, a) for a in (1, 2, 3)]
        self.starts = [0, 0, 0]
        self.wrong_module = 0
        self.goals = {1: 10_000, 2: 70_000, 3: -70_000}
        if net is not None:
            for i, m in enumerate(net.modules):
                def counted(lt, i=i, start=m._start):
                    self.starts[i] += 1
                    start(lt)
                m._start = counted

    def setup(self) -> None:
        for m in self.mods:
            m.define_status(codec.SEND_POS | codec.SEND_AUX)
            m.set_gains(DEFAULT_GAINS)
            m.clear_bits()
            m.enable()
            self.bus.transact(codec.reset_pos(m.address, position=self.goals[m.address]))
            m.set_group(GROUP, leader=m.address == 1)

    def check(self, m: Module, st: codec.Status) -> str | None:
        lo, hi = BANDS[m.address]
        if st.position is not None and not lo - 500 <= st.position <= hi + 500:
            if any(b[0] - 500 <= st.position <= b[1] + 500 for a, b in BANDS.items() if a != m.address):
                self.wrong_module += 1
                return f"module {m.address} reported {st.position}: another module's position"
            return f"module {m.address} reported {st.position}: outside its band"
        return None

    def poll(self) -> str | None:
        for _ in range(3):
            for m in self.mods:
                bad = self.check(m, m.nop())
                if bad:
                    return bad
        return None

    def move(self) -> str | None:
        goals = {a: self.rng.randint(lo, hi) for a, (lo, hi) in BANDS.items()}
        for m in self.mods:  # short moves keep the benchmark quick
            goals[m.address] = max(BANDS[m.address][0], min(BANDS[m.address][1],
                                   self.goals[m.address] + (goals[m.address] - self.goals[m.address]) // 4))
        for m in self.mods:
            m.load_position(goals[m.address], VEL, ACC, start=False)
        self.goals = dict(goals)  # from here the modules may be heading there
        self.bus.start_move(GROUP)
        deadline = self.bus.clock.now() + 5.0
        while True:
            sts = [m.nop() for m in self.mods]
            for m, st in zip(self.mods, sts):
                bad = self.check(m, st)
                if bad:
                    return bad
            if all(st.move_done for st in sts):
                break
            if self.bus.clock.now() > deadline:
                return "move did not finish in 5 s"
        self.bus.clock.sleep(0.02)
        for m in self.mods:
            p = m.position()
            if abs(p - goals[m.address]) > 3:
                return f"module {m.address} done at {p}, goal {goals[m.address]}"
        return None

    def jog(self) -> str | None:
        m = self.rng.choice(self.mods)
        lo, hi = BANDS[m.address]
        direction = 1 if self.goals[m.address] < (lo + hi) // 2 else -1
        m.load_velocity(direction * JOG, ACC)
        self.bus.clock.sleep(0.05)
        bad = self.poll()
        m.load_velocity(0, ACC)
        self.bus.clock.sleep(0.05)
        self.goals[m.address] = m.position()
        return bad or self.check(m, m.nop())

    def recover(self, hang_s: float) -> str | None:
        """What an operator does after a clear error: reconnect, stop, re-read the state."""
        t0 = time.monotonic()
        while True:
            try:
                self.bus.reopen()
                report = self.bus.stop_all()
                if not report.ok:
                    raise NmcError(report.sentence())
                for m in self.mods:
                    m.enable()
                    st = m.nop()
                    bad = self.check(m, st)
                    if bad:
                        return bad
                    self.goals[m.address] = st.position
                return None
            except NmcError:
                if time.monotonic() - t0 > hang_s:
                    return "hang: the link did not come back"
                time.sleep(0.2)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--faults", type=int, default=200)
    ap.add_argument("--kinds", default="stall,drop,flip,garbage,blackout,disconnect")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--target", default=None, help="HOST:PORT of an external `cmm sim --tcp` (default: served here)")
    ap.add_argument("--hang", type=float, default=15.0, help="an operation longer than this (s) counts as a hang")
    args = ap.parse_args()
    kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
    rng = random.Random(args.seed)

    net = served = None
    if args.target is None:
        net = SimNetwork(3, wire_time=True)
        served = serve_tcp(net)
        target = served.url
    else:
        target = args.target
    proxy = FaultProxy(target, seed=args.seed)
    bus = Bus(proxy.url, expected_modules=3)
    bus.initialize(115200)
    bench = Bench(bus, proxy, net, rng)
    bench.setup()

    outcome: dict[str, Counter] = defaultdict(Counter)
    doubled = hangs = 0
    op_times: list[float] = []
    wrong_examples: list[str] = []
    errors: Counter = Counter()
    t_start = time.monotonic()
    for i in range(args.faults):
        kind = kinds[i % len(kinds)]
        fault = make_fault(kind, rng)
        op = rng.choice(("poll", "poll", "move", "jog"))
        before = list(bench.starts)
        # the fault is armed just before a random one of the operation's first commands, so it can hit a
        # LOAD_TRAJ, a START_MOVE or a poll alike
        skip = [rng.randint(0, 6)]

        def arm(entry, fault=fault, skip=skip) -> None:
            if entry.direction == "tx" and entry.data[:1] == b"\xaa" and skip[0] >= 0:
                skip[0] -= 1
                if skip[0] < 0:
                    proxy.inject(fault)

        unsubscribe = bus.trace.subscribe(arm)
        t0 = time.monotonic()
        try:
            bad = getattr(bench, op)()
            while (proxy.pending() or skip[0] >= 0) and bad is None:  # not hit yet: keep the link busy
                bad = bench.poll()
            result = "wrong state" if bad else "recovered"
        except NmcError as exc:
            errors[f"{fault.kind}: {exc}"[:110]] += 1
            bad = bench.recover(args.hang)
            result = "wrong state" if bad else "clear error"
            if not bad and not str(exc):
                bad, result = "an error without a message", "wrong state"
        unsubscribe()
        dt = time.monotonic() - t0
        op_times.append(dt)
        if dt > args.hang:
            hangs += 1
        if bad and len(wrong_examples) < 5:
            wrong_examples.append(f"{fault.describe()} during {op}: {bad}")
        # a coordinated move starts each module once; a jog's velocity settings are meant to be repeatable
        if op != "jog" and any(after - b > 1 for after, b in zip(bench.starts, before)):
            doubled += 1
        outcome[kind][result] += 1
        if (i + 1) % 100 == 0:
            print(f"  ... {i + 1} faults, {time.monotonic() - t_start:.0f} s", flush=True)

    print(f"\n{args.faults} faults through the TCP proxy ({'served here' if net else target}), seed {args.seed}")
    print(f"  {'fault':<11} {'recovered':>9} {'clear error':>12} {'wrong state':>12}")
    total: Counter = Counter()
    for kind in kinds:
        c = outcome[kind]
        total.update(c)
        print(f"  {kind:<11} {c['recovered']:>9} {c['clear error']:>12} {c['wrong state']:>12}")
    print(f"  {'total':<11} {total['recovered']:>9} {total['clear error']:>12} {total['wrong state']:>12}")
    print(f"  wrong-module replies: {bench.wrong_module}   doubled moves: "
          f"{doubled if net else 'not counted (external simulator)'}   hangs (> {args.hang:g} s): {hangs}")
    print(f"  time per fault and operation: median {statistics.median(op_times) * 1000:.0f} ms, "
          f"max {max(op_times) * 1000:.0f} ms")
    s = bus.stats
    print(f"  bus: {s['transactions']} transactions, {s['resyncs']} resynchronisations, {s['discarded']} stale bytes "
          f"discarded, {s['verified']} motion starts checked on the modules, {s['suspect']} suspect replies")
    for line in wrong_examples:
        print(f"  ! {line}")
    for text, n in errors.most_common(8):
        print(f"  clear error x{n}: {text}")
    bus.close()
    proxy.close()
    if served is not None:
        served.close()


if __name__ == "__main__":
    main()
