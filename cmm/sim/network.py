"""The simulated NMC network: a byte stream in, a byte stream out, a clock.

Time is kept in integer nanoseconds. Base tick k covers [k*T, (k+1)*T) with
T = 0.512 ms; at its end the plants move, the tick hooks run, every module
runs its servo code (every SR-th base tick), and then the commands that fully
arrived during the tick execute and their replies start.

Wire model
- Host bytes are timestamped on arrival (with wire-time emulation each byte
  takes 10 bits at the host's baud rate, back to back), then parsed byte by
  byte by every module whose communications are enabled: a module ignores
  everything until the 0xAA header, then counts the packet length from the
  command byte's high nibble. Nulls therefore complete a truncated packet,
  which then fails its checksum (the host flushes that reply).
- Any host byte arriving while a reply is pending or being sent aborts the
  rest of that reply (all modules stop transmitting).
- Baud: each module has its own rate (19200 at power-up; SET_BAUD switches
  after the reply). The rate comes from the divisor and the module's 20 MHz
  clock (rate = 20 MHz / (16 (BRD + 1)), the PIC's UART formula; it gives the
  thesis's table 129/63/20/10 and Kerr's library's 64/21/10 alike); a host
  whose rate is within UART_TOLERANCE of it is understood, as by a real UART.
  A divisor whose rate is within the tolerance of no standard PC rate would
  make the module unreachable until a power cycle: the simulated module keeps
  its rate instead (a choice; the data sheet is silent). If the host's rate
  does not match a module's, the module receives nothing from the host
  (framing errors, dropped) and the host receives nothing from it: the host
  sees a time-out, as with real hardware whose garbage bytes a driver would
  discard. Each host byte is judged by the host's rate when it was written,
  so a host may switch its rate as soon as its command is sent, however long
  the emulated wire takes. ``host_baud=None`` means the host always matches
  (a TCP link, which carries no line rate).
- Two modules replying to the same packet (duplicate addresses) collide:
  their bytes are OR-ed, as garbage a host checksum will reject.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from cmm.nmc import codec as c
from cmm.sim.picservo import UART_TOLERANCE, PicServo, divisor_rate, rates_match, standard_rate
from cmm.sim.plant import DEFAULT_PLANT, Plant, PlantParams
from cmm.sim.transport import SimTransport

TICK_NS = 512_000
MAX_LAG_NS = 250_000_000
# Called once per servo tick with the network and the tick's index. A tick's time is its index * TICK_NS:
# ``network.now_ns`` is where the current batch started (``advance_to`` runs many ticks in one call, and sets it
# at the end), so a hook that stamped its samples with it would give every tick of a batch the same time.
TickHook = Callable[["SimNetwork", int], None]

FIRMWARE_VERSIONS = {"pic-servo": 4, "pic-servo-sc": 10}


def byte_ns(baud: int) -> int:
    """Wire time of one byte (start + 8 data + stop bits)."""
    return round(10e9 / baud)


class _Parser:
    """One module's receiver state: the packet being framed (its bytes, its length once the command byte is in;
    framed byte by byte in :meth:`SimNetwork._feed` and :meth:`SimNetwork._feed_together`)."""

    __slots__ = ("buf", "need")

    def __init__(self) -> None:
        self.buf = bytearray()
        self.need = 0

    def reset(self) -> None:
        self.buf.clear()
        self.need = 0


@dataclass
class _Arrival:
    """A packet one module finished receiving."""

    tick: int  # executes at the end of this base tick
    seq: int  # host byte counter at completion (later bytes abort the reply)
    module: int
    packet: bytes


class SimNetwork:
    """A chain of simulated PIC-SERVO modules on one NMC bus.

    ``modules[0]`` is the module furthest from the host (ADDR_IN grounded):
    it answers first at 0x00 and so usually becomes address 1.
    """

    def __init__(self, n_modules: int = 3, version: int | None = None, wire_time: bool = False,
                 realtime: bool = False, firmware: str = "pic-servo", seed: int | None = None,
                 plant: PlantParams | list[PlantParams] = DEFAULT_PLANT,
                 tick_hook: TickHook | None = None) -> None:
        if not 1 <= n_modules <= 32:
            raise ValueError(f"an NMC network holds 1 to 32 modules, not {n_modules}")
        if firmware not in c.BAUD_DIVISORS:
            raise ValueError(f"unknown firmware {firmware!r}; known: {', '.join(c.BAUD_DIVISORS)}")
        self.firmware = firmware
        self.version = FIRMWARE_VERSIONS[firmware] if version is None else version
        self.wire_time = wire_time
        self.realtime = realtime
        self.seed = seed  # reserved for stochastic plant options; the model is deterministic
        params = plant if isinstance(plant, list) else [plant] * n_modules
        self.plants = [Plant(p) for p in params]
        self.modules = [PicServo(p, self.version, firmware) for p in self.plants]
        self._parsers = [_Parser() for _ in self.modules]
        self.tick_hooks: list[TickHook] = [tick_hook] if tick_hook else []
        self._watchers: set[int] = set()  # ids of hooks that only read the axes (see add_tick_hook)
        self.host_baud: int | None = c.POWER_UP_BAUD
        self.tick = 0  # completed base ticks
        self.now_ns = 0
        self._rx: deque[tuple[int, int, int | None]] = deque()  # (arrival ns, byte, host rate) not yet fed
        self._host_tx_free = 0  # when the host's line is free again
        self._seq = 0  # host bytes fed so far
        self._arrivals: list[_Arrival] = []
        self._tx: deque[tuple[int, int, int]] = deque()  # (start ns, end ns, byte) on the status line
        self._tx_free = 0
        self.host_in = bytearray()  # bytes the host has received and not read
        self._t0 = time.perf_counter_ns()
        # virtual clock: at most this many simulated seconds per wall second (None: as fast as the CPU allows)
        self.pace: float | None = None
        self._pace_ref: tuple[int, int] | None = None  # (wall ns, simulated ns) the pace counts from
        self.lock = threading.RLock()  # held by a serving thread around every step
        self._update_chain()

    def transport(self, baudrate: int = c.POWER_UP_BAUD, timeout: float | None = 0.1) -> SimTransport:
        """An in-process pyserial-like port on this network."""
        return SimTransport(self, baudrate=baudrate, timeout=timeout)

    # --- world API ------------------------------------------------------------
    def add_tick_hook(self, hook: TickHook, *, reads_axes_only: bool = False) -> None:
        """``hook(network, tick)`` runs every base tick after the plants move,
        before the modules read their inputs (capture logic).

        ``reads_axes_only``: the hook's effect is a function of the axis positions alone (the probe, home
        switches), so while every module is provably idle the ticks may still be skipped: the hook runs again
        on the last tick of the skipped stretch. Other hooks (a test recording every tick) run on every tick."""
        self.tick_hooks.append(hook)
        if reads_axes_only:
            self._watchers.add(id(hook))

    def set_inputs(self, axis: int, **levels: bool) -> None:
        """Set LIMIT1 / LIMIT2 / INDEX levels of ``modules[axis]`` (see Plant.set_inputs)."""
        self.plants[axis].set_inputs(**levels)

    def set_power(self, on: bool, axis: int | None = None) -> None:
        for p in self.plants if axis is None else [self.plants[axis]]:
            p.set_power(on)

    def power_cycle(self) -> None:
        """Switch the modules' logic supply off and on: power-up state (SC modules
        restore what HARD_RESET saved in EEPROM), the address chain re-forms."""
        for m, parser in zip(self.modules, self._parsers):
            m.power_up()
            parser.reset()
        self._arrivals.clear()
        self._tx.clear()
        self._update_chain()

    @property
    def seconds(self) -> float:
        return self.now_ns * 1e-9

    # --- host side --------------------------------------------------------------
    def host_write(self, data: bytes) -> None:
        """Bytes the host puts on the command line now."""
        self.sync()
        t = self.now_ns
        rate = self.host_baud  # each byte is judged at the rate it was sent with
        if self.wire_time:
            per = byte_ns(rate or self.modules[0].baud)
            t = max(t, self._host_tx_free)
            for b in data:
                t += per
                self._rx.append((t, b, rate))
            self._host_tx_free = t
        elif not self._rx and data:
            self._feed_together(t, data, rate)
        else:
            for b in data:
                self._rx.append((t, b, rate))
            self._feed_until(t, inclusive=True)

    def host_read(self, size: int | None = None) -> bytes:
        """Take up to ``size`` received bytes (all if None)."""
        buf = self.host_in
        n = len(buf) if size is None else min(size, len(buf))
        out = bytes(buf[:n])
        del buf[:n]
        return out

    def busy(self) -> bool:
        """Something is in flight: a byte on either line or a command waiting for its tick."""
        return bool(self._rx or self._arrivals or self._tx)

    def next_event_ns(self) -> int:
        """When something observable to the host may next happen."""
        t = (self.tick + 1) * TICK_NS
        if self._tx and self._tx[0][1] < t:
            t = self._tx[0][1]
        return t

    # --- clock ------------------------------------------------------------------
    def wall_ns(self) -> int:
        return time.perf_counter_ns() - self._t0

    def start_realtime(self) -> None:
        """Switch to the wall clock from the current simulated time on."""
        self.realtime = True
        self._t0 = time.perf_counter_ns() - self.now_ns

    def set_pace(self, pace: float | None) -> None:
        """Cap the virtual clock at ``pace`` simulated s per wall s from now on (None: uncapped). The pace counts
        from this moment: a reference point kept from the old pace would make the clock wait (or race) to make
        up the difference."""
        self._pace_ref = None  # whatever hold_pace reads next is a fresh reference point
        self.pace = pace
        self._pace_ref = None

    def hold_pace(self) -> None:
        """On a paced virtual clock, wait (wall time, without the lock) until the wall clock
        catches up with simulated time / pace. Lag beyond 50 ms is forgiven, not caught up."""
        pace = self.pace
        if not pace or self.realtime:
            return
        wall, sim = time.perf_counter_ns(), self.now_ns
        ref = self._pace_ref
        if ref is None:
            self._pace_ref = (wall, sim)
            return
        ahead_ns = ref[0] + (sim - ref[1]) / pace - wall
        if ahead_ns > 0:
            time.sleep(ahead_ns * 1e-9)
        elif ahead_ns < -50e6:
            self._pace_ref = (wall, sim)

    def sync(self) -> None:
        """In real time, catch the simulation up with the wall clock (in one batch).

        If the CPU cannot keep up for more than MAX_LAG_NS, the lost time is
        dropped rather than replayed, so a stall does not snowball."""
        if self.realtime:
            wall = self.wall_ns()
            if wall - self.now_ns > MAX_LAG_NS:
                self._t0 += wall - self.now_ns - MAX_LAG_NS
                wall = self.now_ns + MAX_LAG_NS
            self.advance_to(wall)

    def advance(self, seconds: float) -> None:
        self.advance_to(self.now_ns + round(seconds * 1e9))

    def advance_to(self, t_ns: int) -> None:
        """Run the network up to time ``t_ns`` (ticks whose end is <= t_ns)."""
        if t_ns <= self.now_ns:
            return
        rx = self._rx
        mods = self.modules
        while True:
            tick = self.tick
            tick_end = (tick + 1) * TICK_NS
            if tick_end > t_ns:
                break
            if rx and rx[0][0] < tick_end:
                self._feed_until(tick_end, inclusive=False)
            if tick_end + TICK_NS <= t_ns:
                for m in mods:  # _skippable's first test inlined: while anything moves, one module is not quiet
                    if not m.quiet:
                        break
                else:
                    if self._skippable():
                        nxt = t_ns if not rx else min(t_ns, rx[0][0])
                        skip = nxt // TICK_NS - tick - 1
                        if skip > 0:
                            self.tick += skip  # every module is provably idle: skip exactly
                            continue
            # _run_tick inlined (every base tick of a moving machine)
            for m in mods:
                if not m.quiet:
                    m.plant.step()
            for hook in self.tick_hooks:
                hook(self, tick)
            for m in mods:
                if not m.quiet and (m.sr == 1 or tick % m.sr == 0):
                    m.servo()
            if self._arrivals:
                self._execute(tick, tick_end)
            self.tick = tick + 1
        self._feed_until(t_ns, inclusive=True)
        self.now_ns = t_ns
        self._deliver(t_ns)

    def _skippable(self) -> bool:
        for m in self.modules:  # first: asked every tick, and while anything moves a module is not quiet
            if not m.quiet:
                return False
        if self._arrivals or self._tx:
            return False
        for hook in self.tick_hooks:
            if id(hook) not in self._watchers:
                return False
        return True

    # --- internals ----------------------------------------------------------------
    def _feed_until(self, t_ns: int, inclusive: bool) -> None:
        rx = self._rx
        while rx and (rx[0][0] <= t_ns if inclusive else rx[0][0] < t_ns):
            t, b, rate = rx.popleft()
            self._feed(t, b, rate)

    def _feed(self, t: int, b: int, host_baud: int | None) -> None:
        """One host byte arriving at ``t`` (a byte with wire time, or behind bytes still on the wire)."""
        self._feed_together(t, bytes((b,)), host_baud)

    def _feed_together(self, t: int, data: bytes, host_baud: int | None) -> None:
        """Bytes that all arrive at ``t``: a new byte aborts the reply in progress, and every module that listens at
        the host's rate frames them; the packets completed arrive in the order of the byte that completed them, then
        of the module (one pass per module over the bytes: a whole transaction's packet arrives so)."""
        seq0 = self._seq
        self._seq = seq0 + len(data)
        tx = self._tx
        if tx:  # the first byte aborts the reply in progress (the later ones find nothing more to abort)
            while tx and tx[-1][0] >= t:
                tx.pop()
            self._tx_free = tx[-1][1] if tx else t
        tick = t // TICK_NS
        if tick < self.tick:
            tick = self.tick
        span = None if host_baud is None else UART_TOLERANCE * host_baud
        done: list[tuple[int, int, bytes]] = []
        header = c.HEADER
        for i, m in enumerate(self.modules):
            if not m.comms_enabled:
                continue
            if span is not None and not (host_baud > 0 and abs(m.line_rate - host_baud) <= span):
                continue
            parser = self._parsers[i]
            buf = parser.buf
            for k, b in enumerate(data):
                if not buf:
                    if b == header:
                        buf.append(b)
                    continue
                buf.append(b)
                n = len(buf)
                if n == 3:
                    parser.need = 4 + (b >> 4)
                elif n > 3 and n == parser.need:
                    done.append((seq0 + k + 1, i, bytes(buf)))
                    buf.clear()
        if done:
            done.sort(key=lambda d: (d[0], d[1]))
            self._arrivals.extend(_Arrival(tick, seq, i, packet) for seq, i, packet in done)

    def _execute(self, tick: int, tick_end: int) -> None:
        due = [a for a in self._arrivals if a.tick <= tick]
        self._arrivals = [a for a in self._arrivals if a.tick > tick]
        replies: dict[int, list[tuple[PicServo, bytes]]] = {}
        for a in due:
            m = self.modules[a.module]
            reply = self._execute_one(m, a.packet)
            if reply is not None and a.seq == self._seq:  # no newer byte has arrived
                replies.setdefault(a.seq, []).append((m, reply))
        for group in replies.values():
            self._send(group, tick_end)
        for a in due:  # SET_BAUD takes effect once its reply has been sent
            m = self.modules[a.module]
            if m.pending_baud is not None:
                (m.baud, m.line_rate), m.pending_baud = m.pending_baud, None

    def _execute_one(self, m: PicServo, packet: bytes) -> bytes | None:
        """Execute a packet a module received; return its reply if it sends one."""
        addr = packet[1]
        individual = addr == m.address
        if not individual and addr != m.group:
            return None
        answers = individual or m.leader
        if sum(packet[1:-1]) & 0xFF != packet[-1]:
            reply = m.checksum_error_reply()
            return reply if answers else None
        code = packet[2] & 0x0F
        data = packet[3:-1]
        reply = m.execute(code, data)
        if code == c.SET_BAUD and len(data) == 1:
            rate = divisor_rate(data[0], self.firmware)
            nominal = standard_rate(rate)
            if nominal is not None:  # else no host could reach the module again: it keeps its rate
                m.pending_baud = (nominal, rate)
        elif code in (c.SET_ADDR, c.HARD_RESET):
            if code == c.HARD_RESET:
                self._parsers[self.modules.index(m)].reset()
            self._update_chain()
        return reply if answers else None

    def _send(self, group: list[tuple[PicServo, bytes]], tick_end: int) -> None:
        reply = group[0][1]
        for _, other in group[1:]:  # bus collision
            reply = bytes(x | y for x, y in zip(reply, other))
        m = group[0][0]
        matched = rates_match(m.line_rate, self.host_baud)
        per = byte_ns(m.baud) if self.wire_time else 0
        t = max(tick_end, self._tx_free)
        for b in reply:
            start = t
            t += per
            if matched:
                self._tx.append((start, t, b))
        self._tx_free = t

    def _update_chain(self) -> None:
        """ADDR_OUT of module i drives ADDR_IN of module i+1; modules[0] is grounded.

        A module latches its communications on once it sees ADDR_IN low and
        keeps them until its own reset."""
        low = True
        for m in self.modules:
            if low and not m.comms_enabled:
                m.comms_enabled = True
            low = m.addr_out_low

    def _deliver(self, t_ns: int) -> None:
        tx = self._tx
        if tx and tx[0][1] <= t_ns:
            out = self.host_in
            while tx and tx[0][1] <= t_ns:
                out.append(tx.popleft()[2])
