"""Link robustness: the bus against injected faults on real simulator bytes (virtual clock, and one TCP proxy run).

Three modules are parked at positions far apart, so a reply taken for the
wrong module shows as a wrong position.
"""

from __future__ import annotations

import contextlib
import random
import zlib

import pytest
import serial

from cmm.nmc import codec
from cmm.nmc.bus import IDLE_PATIENCE, Bus, LinkError, NmcError
from cmm.nmc.faults import Fault, FaultProxy, FaultyTransport
from cmm.nmc.module import Module
from cmm.sim.network import SimNetwork
from cmm.sim.plant import DEFAULT_GAINS
from cmm.sim.serve import serve_tcp
from test_bus import ready  # one start-up helper for the bus tests

PARK = {1: 5000, 2: 10000, 3: -25000}  # the swap: [-25000, 5000, 10000] published for these
VEL = codec.velocity_to_fixed(50, 500)
ACC = codec.acceleration_to_fixed(500, 500)




def parked(seed: int = 1) -> tuple[SimNetwork, FaultyTransport, Bus, list[Module]]:
    net = SimNetwork(3, wire_time=True)
    port = FaultyTransport(net.transport(), seed=seed)
    bus = Bus(port)
    bus.initialize(115200, expected_modules=3)
    mods = ready(bus)
    for m in mods:  # put each module where no other is: RESET_POS with a set position
        bus.transact(codec.reset_pos(m.address, position=PARK[m.address]))
    return net, port, bus, mods


@contextlib.contextmanager
def faulty_machine(seed: int):
    """(simulated CMM, fault-injecting transport, connected machine) for machine-level fault tests."""
    from stations import Stations

    with Stations() as built:
        sim, machine, _ = built.machine(link=lambda port: FaultyTransport(port, seed=seed))
        yield sim, machine.bus.port, machine


def count_starts(net: SimNetwork) -> list[int]:
    """How many times each simulated module started a trajectory (a doubled move starts twice)."""
    counts = [0] * len(net.modules)
    for i, m in enumerate(net.modules):
        def counted(lt, i=i, start=m._start):
            counts[i] += 1
            start(lt)
        m._start = counted
    return counts


def positions_ok(mods: list[Module], where: dict[int, int], tol: int = 3) -> list[str]:
    wrong = []
    for m in mods:
        p = m.nop().position
        if abs(p - where[m.address]) > tol:
            wrong.append(f"module {m.address} reported {p}, is at {where[m.address]}")
    return wrong


def test_late_replies_after_stalls_are_never_taken_for_another_module():
    net, port, bus, mods = parked()
    rng = random.Random(7)
    wrong = []
    for _ in range(25):
        port.inject(Fault("stall", rng.choice(["rx", "tx"]), duration=rng.uniform(0.05, 0.5)))
        for _ in range(2):
            wrong += positions_ok(mods, PARK)
    assert wrong == []
    # the stalls really made replies late: the bus resynchronised and threw late bytes away
    assert bus.stats["resyncs"] >= 20 and bus.stats["discarded"] >= 20


@pytest.mark.parametrize("fault", [
    Fault("drop", "rx"), Fault("drop", "tx"), Fault("drop", "rx", count=5), Fault("flip", "rx"),
    Fault("flip", "tx"), Fault("flip", "rx", count=3), Fault("garbage", "rx"), Fault("garbage", "rx", count=7),
    Fault("garbage", "tx", count=4), Fault("blackout", "both", duration=0.3), Fault("stall", "both", duration=0.45),
], ids=lambda f: f.describe().replace(" ", "-"))
def test_each_fault_is_recovered_with_the_right_replies(fault):
    net, port, bus, mods = parked(seed=zlib.crc32(fault.describe().encode()))
    for _ in range(5):
        port.inject(fault)
        assert positions_ok(mods, PARK) == []
    assert not port.pending()
    # noise before a command header is ignored by the modules (they wait for 0xAA): nothing to retry
    assert bus.stats["retries"] >= 1 or (fault.kind, fault.direction) == ("garbage", "tx")


def test_a_long_blackout_is_one_link_error_then_the_link_comes_back():
    net, port, bus, mods = parked()
    port.inject(Fault("blackout", "both", duration=20.0))
    t0 = bus.clock.now()
    with pytest.raises(LinkError, match="faulty:sim://") as err:
        mods[1].nop()
    # a time-out storm ends in a clear error, not a hang (the axes stand still: after the idle patience)
    assert bus.clock.now() - t0 < IDLE_PATIENCE + 3.5
    assert "check the cable" in str(err.value)
    bus.clock.sleep(20.0)
    bus.reopen()
    assert positions_ok(mods, PARK) == []


@pytest.mark.parametrize("error, raised", [("serial", serial.SerialException), ("oserror", OSError),
                                           ("write_timeout", serial.SerialTimeoutException)])
def test_a_disconnect_surfaces_as_link_error_only(error, raised):
    net, port, bus, mods = parked()
    port.inject(Fault("disconnect", error=error))
    with pytest.raises(raised):  # what the port itself raises (pyserial's exceptions)
        port.write(codec.nop(1))
    with pytest.raises(LinkError, match=r"serial link faulty:sim:// failed while \w+ .*\(module 2\)") as err:
        mods[1].nop()
    assert isinstance(err.value.__cause__, raised) and err.value.port == "faulty:sim://"
    assert not bus.link_up
    report = bus.stop_all()
    assert not report.ok and report.silent == (1, 2, 3) and "STOP NOT CONFIRMED" in report.sentence()
    port.restore()
    bus.reopen()  # modules keep address, rate and position across a reconnect
    assert bus.link_up and positions_ok(mods, PARK) == []


def test_stop_all_on_a_noisy_link_stops_every_axis_and_says_so():
    net, port, bus, mods = parked()
    for m in mods:
        m.load_velocity(codec.velocity_to_fixed(20, 500), ACC)
    bus.clock.sleep(0.3)
    port.inject(Fault("garbage", "tx", count=6))
    port.inject(Fault("drop", "rx", count=3))
    report = bus.stop_all()
    assert report.ok and report.acknowledged == (1, 2, 3), report.sentence()
    before = [m.position() for m in mods]
    bus.clock.sleep(0.3)
    assert [m.position() for m in mods] == pytest.approx(before, abs=2)
    assert all(m.nop().move_done for m in mods)


@pytest.mark.parametrize("fault", [Fault("stall", "rx", duration=0.3), Fault("drop", "rx", count=2),
                                   Fault("drop", "tx"), Fault("stall", "tx", duration=0.2),
                                   Fault("flip", "rx")], ids=lambda f: f.describe().replace(" ", "-"))
def test_a_lost_start_move_reply_never_doubles_the_move(fault):
    net, port, bus, mods = parked()
    starts = count_starts(net)
    goals = {1: 8000, 2: 6000, 3: -20000}
    for m in mods:
        m.set_group(0x80, leader=m.address == 1)
    for m in mods:
        m.load_position(goals[m.address], VEL, ACC, start=False)
    port.inject(fault)  # hits START_MOVE (command or reply)
    bus.start_move(0x80)
    assert not port.pending()
    for m in mods:
        m.wait_move_done(5.0)
    assert starts == [1, 1, 1]
    assert bus.stats["verified"] >= 1  # the modules were asked, START_MOVE was not blindly resent
    assert positions_ok(mods, goals) == []


@pytest.mark.parametrize("fault", [Fault("stall", "rx", duration=0.3), Fault("drop", "tx")],
                         ids=lambda f: f.describe().replace(" ", "-"))
def test_a_lost_reply_to_a_started_move_is_checked_on_the_module(fault):
    net, port, bus, mods = parked()
    starts = count_starts(net)
    port.inject(fault)
    mods[0].load_position(9000, VEL, ACC)  # START_NOW position move
    mods[0].wait_move_done(5.0)
    assert starts[0] == 1 and abs(mods[0].position() - 9000) <= 3
    assert bus.stats["verified"] == 1


def count_commands(net: SimNetwork, code: int) -> list[int]:
    """How many times each simulated module carried out a command (a doubled reset shows as 2)."""
    counts = [0] * len(net.modules)
    for i, m in enumerate(net.modules):
        def counted(c, data, i=i, execute=m.execute):
            counts[i] += c == code
            return execute(c, data)
        m.execute = counted
    return counts


LOST = [Fault("drop", "rx", count=2), Fault("stall", "rx", duration=0.3), Fault("drop", "tx")]  # done, done, not


def inject_at(bus: Bus, port: FaultyTransport, code: int, fault: Fault) -> list[bytes]:
    """Arm ``fault`` as the bus sends the first command ``code``: it hits that command (tx) or its reply (rx),
    not a status read the bus makes before it. Returns the packets it was armed at (one)."""
    hit: list[bytes] = []

    def arm(entry) -> None:
        data = entry.data
        if (entry.direction == "tx" and not hit and len(data) > 3 and data[0] == codec.HEADER
                and data[2] & 0x0F == code):
            hit.append(data)
            port.inject(fault)

    bus.trace.subscribe(arm)
    return hit


@pytest.mark.parametrize("fault", LOST, ids=lambda f: f.describe().replace(" ", "-"))
def test_a_lost_reset_pos_reply_is_recovered_and_never_doubles_the_reset(fault):
    net, port, bus, mods = parked()
    resets = count_commands(net, codec.RESET_POS)
    port.inject(fault)
    mods[1].reset_position()
    assert abs(mods[1].position()) <= 3 and abs(net.modules[1].pos) <= 3
    assert resets == [0, 1, 0] and bus.stats["verified"] == 1
    # the set-position form, to a group: every member checked, none reset twice
    for m in mods:
        m.set_group(0x80, leader=m.address == 1)
    resets[:] = [0, 0, 0]
    port.inject(fault)
    bus.transact(codec.reset_pos(0x80, position=12345))
    assert resets == [1, 1, 1] and [abs(m.position() - 12345) <= 3 for m in mods] == [True] * 3


@pytest.mark.parametrize("fault", LOST, ids=lambda f: f.describe().replace(" ", "-"))
def test_a_lost_reply_to_a_reset_relative_to_home_is_recovered_once(fault):
    net, port, bus, mods = parked()
    net.modules[0].home = 1000  # a capture latched here earlier
    assert mods[0].home_position() == 1000  # ... and read: the bus knows the home register
    resets = count_commands(net, codec.RESET_POS)
    port.inject(fault)
    bus.transact(codec.reset_pos(1, relative_to_home=True))
    assert resets == [1, 0, 0] and abs(mods[0].position() - (PARK[1] - 1000)) <= 3


def test_a_lost_reset_pos_reply_that_cannot_be_told_is_a_link_error_not_a_resend():
    net, port, bus, mods = parked()
    resets = count_commands(net, codec.RESET_POS)
    port.inject(Fault("drop", "rx", count=2))
    with pytest.raises(LinkError, match="reply of module 1 to RESET_POS was lost .* not sent again"):
        bus.transact(codec.reset_pos(1, position=PARK[1] + 2))  # 2 counts from where it reads: done or not?
    assert resets == [1, 0, 0]


@pytest.mark.parametrize("fault", LOST, ids=lambda f: f.describe().replace(" ", "-"))
def test_a_lost_save_as_home_reply_is_recovered(fault):
    net, port, bus, mods = parked()
    inject_at(bus, port, codec.SAVE_AS_HOME, fault)
    mods[2].save_as_home()  # at rest: carried out once or twice, the home register holds the same position
    assert mods[2].home_position() == net.modules[2].home == PARK[3]
    assert bus.stats["verified"] == 1
    # moving, it is told by the home register changing; if it holds no position the axis passed since the
    # command (here 0, thousands of counts behind), the command was lost on the way: sent once more
    assert mods[0].home_position() == 0
    mods[0].load_velocity(codec.velocity_to_fixed(20, 500), ACC)
    bus.clock.sleep(0.2)
    saves = count_commands(net, codec.SAVE_AS_HOME)
    inject_at(bus, port, codec.SAVE_AS_HOME, fault)
    before = bus._last[1][0]  # the last reading before the command
    mods[0].save_as_home()
    assert saves == [1, 0, 0] and bus.stats["verified"] == 2
    assert net.modules[0].home > before + 1000 and mods[0].home_position() == net.modules[0].home


def test_start_up_works_whatever_state_an_earlier_run_left():
    net = SimNetwork(3, wire_time=True)
    bus = Bus(net.transport())
    bus.initialize(115200)
    mods = ready(bus)
    for m in mods:  # what Machine.connect leaves: group 0x80 with a leader, servo on, here even jogging
        m.set_group(0x80, leader=m.address == 1)
        m.load_velocity(codec.velocity_to_fixed(5, 500), ACC)
    bus.transact(codec.set_addr(3, 9, 0x84))  # and one module somewhere odd
    # the old start-up (HARD_RESET to 0xFF only) no longer reaches them
    fresh = Bus(net.transport())
    infos = fresh.initialize(57600, expected_modules=3)
    assert [i.address for i in infos] == [1, 2, 3]
    assert all(m.baud == 57600 for m in net.modules)
    assert all(not m.servo_on for m in net.modules)  # the reset stopped the jog
    # a clean shutdown leaves them as at power-up: Kerr's plain start-up finds them
    fresh.close(release=True)
    assert all(m.address == 0 and m.group == 0xFF and m.baud == 19200 for m in net.modules)
    port = net.transport()
    port.write(bytes(20) + codec.hard_reset(0xFF))
    port.sleep(0.1)
    port.reset_input_buffer()
    port.write(codec.set_addr(0, 1, 0xFF))
    assert len(port.read(2)) == 2


@pytest.mark.parametrize("fault", [Fault("drop", "rx", count=2), Fault("stall", "rx", duration=0.25),
                                   Fault("drop", "tx")], ids=lambda f: f.describe().replace(" ", "-"))
@pytest.mark.parametrize("expected", [None, 3])
def test_discovery_is_not_truncated_by_a_lost_reply(fault, expected):
    net = SimNetwork(3, wire_time=True)
    port = FaultyTransport(net.transport(), seed=3)
    bus = Bus(port)
    port.inject(fault)  # the first SET_ADDR of the chain
    assert len(bus.initialize(expected_modules=expected)) == 3


def test_a_missing_module_is_still_reported_after_the_retries():
    with pytest.raises(NmcError, match="expected 4 modules on the network, found 3 in 3 attempts"):
        Bus(SimNetwork(3).transport()).initialize(expected_modules=4)


def test_faults_through_the_tcp_proxy_in_front_of_the_served_simulator():
    net = SimNetwork(3, wire_time=True)
    with serve_tcp(net) as served, FaultProxy(served.url, seed=5) as proxy:
        bus = Bus(proxy.url)
        try:
            bus.initialize(115200, expected_modules=3)
            mods = ready(bus)
            for m in mods:
                bus.transact(codec.reset_pos(m.address, position=PARK[m.address]))
            for fault in (Fault("stall", "rx", duration=0.3), Fault("garbage", "rx", count=3),
                          Fault("drop", "tx"), Fault("stall", "tx", duration=0.15)):
                proxy.inject(fault)
                assert positions_ok(mods, PARK) == []
            proxy.inject(Fault("disconnect"))
            with pytest.raises(LinkError, match=proxy.url.replace("/", "\\/")):
                for _ in range(50):
                    mods[0].nop()
            bus.reopen()
            assert positions_ok(mods, PARK) == []
            assert proxy.connections == 2 and proxy.disconnects == 1
        finally:
            bus.close()


def test_a_well_formed_reply_that_jumps_to_another_module_position_is_not_accepted():
    """The cross-check behind the resynchronisation: a late reply that slips in exactly between a
    command and its own reply (length and checksum right) is caught by position continuity."""
    net, port, bus, mods = parked()
    genuine_1 = bytes(codec.encode_status(mods[0].nop().status, codec.SEND_POS | codec.SEND_AUX,
                                          position=PARK[1], aux=mods[0].last.aux))
    forged: list[bool] = []

    def slip_in(entry) -> None:
        if entry.direction == "tx" and entry.data == codec.nop(3) and not forged:
            forged.append(True)  # module 1's reply arrives just before module 3 answers
            port.lines.rx.push(genuine_1, bus.clock.now())

    bus.trace.subscribe(slip_in)
    assert mods[2].nop().position == PARK[3]
    assert forged and bus.stats["suspect"] >= 1
    assert positions_ok(mods, PARK) == []


def test_stop_all_on_a_dead_link_reports_quickly_and_on_one_silent_module_stops_the_others():
    net, port, bus, mods = parked()
    for m in mods:
        m.load_velocity(codec.velocity_to_fixed(20, 500), ACC)
    bus.transact(codec.hard_reset(2))  # module 2 loses its address (and stops): it cannot answer any more
    report = bus.stop_all()
    assert report.acknowledged == (1, 3) and report.silent == (2,)
    assert "module 2 stopped answering" in report.reason and "STOP NOT CONFIRMED by module(s) 2" in report.sentence()
    assert all(m.nop().move_done for m in (mods[0], mods[2]))
    port.inject(Fault("blackout", "both", duration=30.0))
    t0 = bus.clock.now()
    report = bus.stop_all()
    assert report.silent == (1, 2, 3) and "link is down" in report.reason
    assert bus.clock.now() - t0 < 3.0  # not a resynchronisation per module


@pytest.mark.parametrize("fault", LOST, ids=lambda f: f.describe().replace(" ", "-"))
def test_a_lost_reply_to_arming_the_probe_capture_is_checked_on_the_module(fault):
    net, port, bus, mods = parked()
    arms = count_commands(net, codec.SET_HOMING)
    inject_at(bus, port, codec.SET_HOMING, fault)  # (the home register, unknown since RESET_POS, is read first)
    st = mods[0].arm_home("limit1", "abrupt")
    assert st.home_in_progress and bus.stats["verified"] == 1 and bus.stats["resyncs"] >= 1
    assert arms == [1, 0, 0]  # carried out once: a command lost on the way (tx) was sent again
    net.set_inputs(0, limit1=True)  # the capture works: it was armed, as asked
    bus.clock.sleep(0.01)
    assert mods[0].home_captured()


def trigger_when_armed(net: SimNetwork, axis: int) -> None:
    """The probe touches on the servo tick after the module's capture is armed."""
    net.add_tick_hook(lambda network, tick: network.set_inputs(axis, limit1=True)
                      if network.modules[axis].home_in_prog else None)


@pytest.mark.parametrize("fault", LOST[:2], ids=lambda f: f.describe().replace(" ", "-"))
def test_a_lost_arming_reply_after_the_capture_fired_reports_the_capture(fault):
    net, port, bus, mods = parked()
    assert mods[0].home_position() == 0  # the home register as it was before arming
    trigger_when_armed(net, 0)
    arms = count_commands(net, codec.SET_HOMING)
    port.inject(fault)
    st = mods[0].arm_home("limit1", "abrupt")
    # the reply the module would have sent a moment later: capture done, not re-armed (that would hide the touch)
    assert not st.home_in_progress and arms == [1, 0, 0] and bus.stats["verified"] == 1
    assert not mods[0].nop().home_in_progress and abs(mods[0].home_position() - PARK[1]) <= 3


@pytest.mark.parametrize("fault", LOST[::2], ids=lambda f: f.describe().replace(" ", "-"))
def test_a_lost_arming_reply_is_a_link_error_when_a_capture_would_have_latched_the_old_home(fault):
    net, port, bus, mods = parked()
    net.modules[0].home = PARK[1]  # an earlier capture here, where the axis stands
    trigger_when_armed(net, 0)
    arms = count_commands(net, codec.SET_HOMING)
    inject_at(bus, port, codec.SET_HOMING, fault)
    with pytest.raises(LinkError, match="reply of module 1 to SET_HOMING was lost .* not sent again"):
        mods[0].arm_home("limit1", "abrupt")  # fired here, or never armed? the home register reads the same
    assert arms == [1, 0, 0] if fault.direction == "rx" else arms == [0, 0, 0]


def test_a_lost_reply_to_a_jog_velocity_is_simply_sent_again():
    net, port, bus, mods = parked()
    port.inject(Fault("drop", "rx", count=2))
    mods[1].load_velocity(codec.velocity_to_fixed(10, 500), ACC)  # velocity mode: the same setting twice is harmless
    bus.clock.sleep(0.3)
    assert mods[1].velocity() == pytest.approx(10 * 500 * codec.TICK_SECONDS, abs=1)
    assert bus.stats["retries"] >= 1 and bus.stats["verified"] == 0


def test_the_machine_never_publishes_one_axis_reading_for_another_under_stalls():
    """The issue's symptom end to end: the machine layer on the simulated CMM through stalled bytes."""
    with faulty_machine(seed=11) as (_, port, machine):
        machine.move_to([4.0, 2.0, 298.0]).wait(60)  # three different readings
        truth = machine.sample().counts
        assert len(set(truth)) == 3
        rng = random.Random(4)
        for _ in range(8):
            port.inject(Fault("stall", rng.choice(["rx", "tx"]), duration=rng.uniform(0.05, 0.5)))
            for _ in range(2):
                assert machine.sample().counts == pytest.approx(truth, abs=3)
        assert machine.bus.stats["resyncs"] >= 6


def test_a_real_jump_is_confirmed_by_the_module_and_accepted():
    """Continuity is a cross-check, not a filter: an axis that really jumped (pushed with the servo
    off, a slipped encoder) is re-read after a resynchronisation and then reported as it is."""
    net, port, bus, mods = parked()
    net.modules[0].enc_offset -= 4000  # the encoder suddenly reads 4000 counts further
    net.modules[0].quiet = False  # (a module at rest is skipped by the simulator until something changes)
    bus.clock.sleep(0.002)
    st = mods[0].nop()
    assert st.position == pytest.approx(PARK[1] + 4000, abs=50)
    assert st.pos_error  # (the servo saw it too: position error limit)
    assert bus.stats["suspect"] == 1
    assert positions_ok(mods[1:], PARK) == []


def test_the_machine_stops_on_a_touch_whose_arming_reply_was_lost():
    """End to end: the probe touches just after X's capture is armed, and that SET_HOMING reply is lost.
    The move must not start as if nothing had happened: the bus reports the capture, the machine stops."""
    from cmm.machine.motion import ContactError

    with faulty_machine(seed=12) as (sim, port, machine):
        machine.move_to([30.0, 20.0, 280.0]).wait(30)  # away from 0 counts, where the home register reads 0
        x = machine.modules[0]
        arms = count_commands(sim.network, codec.SET_HOMING)

        def probe(network, tick):
            if arms[0]:  # deflected from the tick after X is armed for this move, for good
                for i in range(3):
                    network.set_inputs(i, limit1=True)

        sim.network.add_tick_hook(probe)
        plain_arm = x.arm_home

        def arm_with_lost_reply(*args, **kwargs):
            port.inject(Fault("drop", "rx", count=2))
            return plain_arm(*args, **kwargs)

        x.arm_home = arm_with_lost_reply
        start = machine.position
        move = machine.move_to(start + [20.0, 0.0, -5.0])
        with pytest.raises(ContactError, match="unexpected probe contact"):
            move.wait(10)
        assert arms[0] == 1 and machine.bus.stats["verified"] >= 1  # X was not armed again over the touch
        machine.run_for(0.2)
        assert not machine.busy and machine.position == pytest.approx(start, abs=0.01)


def test_a_reply_the_host_read_late_is_not_a_continuity_suspect_but_a_swapped_one_still_is():
    """The continuity window starts when the previous request was sent (the module samples after it
    arrives), not when its reply was read: a host thread scheduled late after reading a reply must not
    make the next correct reply look like a jump. A reply of another module still is one."""
    net, port, bus, mods = parked()
    mods[0].load_velocity(codec.velocity_to_fixed(20, 500), ACC)  # 10,000 counts/s
    bus.clock.sleep(0.3)  # at speed
    sent: list[bytes] = []

    def read_late(entry) -> None:  # every other reply of module 1 is read 50 ms late (host thread preempted)
        if entry.direction == "tx":
            sent.append(entry.data)
        elif (entry.direction == "rx" and not entry.note and sent and sent[-1] == codec.nop(1)
              and sent.count(sent[-1]) % 2):
            bus.clock.sleep(0.05)  # 500 counts of travel that the reply's receipt time knows nothing of

    unsubscribe = bus.trace.subscribe(read_late)
    readings = [mods[0].nop().position for _ in range(20)]
    assert bus.stats["suspect"] == 0 and bus.stats["resyncs"] == 0
    assert max(b - a for a, b in zip(readings, readings[1:])) >= 450  # it did travel while a reading waited
    # the same late reading with module 2's reply slipped in before module 1's own: caught
    genuine_2 = bytes(codec.encode_status(mods[1].nop().status, codec.SEND_POS | codec.SEND_AUX,
                                          position=PARK[2], aux=mods[1].last.aux))
    forged: list[bool] = []

    def slip_in(entry) -> None:
        if entry.direction == "tx" and entry.data == codec.nop(1) and not forged:
            forged.append(True)
            port.lines.rx.push(genuine_2, bus.clock.now())

    bus.trace.subscribe(slip_in)
    st = mods[0].nop()
    unsubscribe()
    assert forged and bus.stats["suspect"] == 1
    assert abs(st.position - net.modules[0].pos) <= 600 and abs(st.position - PARK[2]) > 1000  # its own reply
    assert positions_ok(mods[1:], PARK) == []


JOG = codec.velocity_to_fixed(20, 500)  # 10,000 counts/s


def jogging(fault_seed: int = 1) -> tuple[SimNetwork, FaultyTransport, Bus, list[Module]]:
    """Parked, then module 1 jogs at speed; its home register is unknown to the bus (not read since RESET_POS)."""
    net, port, bus, mods = parked(fault_seed)
    mods[0].load_velocity(JOG, ACC)
    bus.clock.sleep(0.2)
    assert 1 not in bus._home  # what this test is about: a command whose home register was not known before
    return net, port, bus, mods


@pytest.mark.parametrize("fault", LOST[:2], ids=lambda f: f.describe().replace(" ", "-"))
def test_a_capture_that_fired_while_moving_with_the_home_register_unknown_is_reported(fault):
    """Arming right after RESET_POS on a moving axis, the probe touches at once, the reply is lost: the home
    register is read back before arming, so its change tells the capture fired (never re-armed over it)."""
    net, port, bus, mods = jogging()
    trigger_when_armed(net, 0)
    arms = count_commands(net, codec.SET_HOMING)
    inject_at(bus, port, codec.SET_HOMING, fault)
    st = mods[0].arm_home("limit1", "abrupt")
    assert not st.home_in_progress and arms == [1, 0, 0] and bus.stats["verified"] == 1
    latched = net.modules[0].home
    assert latched > PARK[1] + 1000 and mods[0].home_position() == latched
    assert mods[0].nop().move_done and abs(mods[0].position() - latched) <= 50  # the capture stopped it


@pytest.mark.parametrize("action", ["abrupt", "off"])
def test_an_arming_lost_on_the_way_to_a_moving_axis_is_sent_again_once(action):
    """Not armed, and the home register holds no position the axis can have passed since the command
    (the continuity bound; with "off" the axis may coast after a capture, so only the way there counts):
    nothing fired, so arming again is harmless."""
    net, port, bus, mods = jogging()
    arms = count_commands(net, codec.SET_HOMING)
    inject_at(bus, port, codec.SET_HOMING, Fault("drop", "tx"))
    st = mods[0].arm_home("limit1", action)
    assert st.home_in_progress and arms == [1, 0, 0] and bus.stats["verified"] == 1
    net.set_inputs(0, limit1=True)  # armed, as asked: the capture works
    bus.clock.sleep(0.01)
    assert mods[0].home_captured() and abs(net.modules[0].home - st.position) < 300


@pytest.mark.parametrize("fault", LOST, ids=lambda f: f.describe().replace(" ", "-"))
def test_a_lost_save_as_home_reply_on_a_moving_axis_with_the_home_register_unknown_is_recovered(fault):
    net, port, bus, mods = jogging()
    saves = count_commands(net, codec.SAVE_AS_HOME)
    inject_at(bus, port, codec.SAVE_AS_HOME, fault)
    before = bus._last[1][0]  # the last reading before the command
    st = mods[0].save_as_home()
    assert saves == [1, 0, 0] and bus.stats["verified"] == 1  # done (rx) or sent once more (tx), never twice
    assert before < net.modules[0].home <= st.position + 3 and mods[0].home_position() == net.modules[0].home


def test_a_lost_save_as_home_that_cannot_be_told_is_a_link_error_not_a_resend():
    """Moving, the command lost on the way, and the old home value lies just ahead on the axis's path:
    it may have been saved there, or not at all; saving again would latch another position."""
    net, port, bus, mods = jogging()
    net.modules[0].home = net.modules[0].pos + 200  # passed 20 ms from now
    saves = count_commands(net, codec.SAVE_AS_HOME)
    inject_at(bus, port, codec.SAVE_AS_HOME, Fault("drop", "tx"))
    with pytest.raises(LinkError, match="reply of module 1 to SAVE_AS_HOME was lost .* not sent again"):
        mods[0].save_as_home()
    assert saves == [0, 0, 0]


@pytest.mark.parametrize("code", [codec.SET_HOMING, codec.SAVE_AS_HOME], ids=["SET_HOMING", "SAVE_AS_HOME"])
def test_a_command_lost_on_the_way_right_after_start_up_is_sent_again_once(code):
    """Start-up: the replies carry no position yet (status byte only), so nothing told where the axis stood
    before the command; the bus reads it back first, so at rest a home register away from the axis says the
    command was not carried out."""
    net = SimNetwork(3, wire_time=True)
    port = FaultyTransport(net.transport(), seed=2)
    bus = Bus(port)
    bus.initialize(115200, expected_modules=3)
    x = Module(bus, 1)
    x.set_gains(DEFAULT_GAINS)
    x.enable()
    x.load_position(1500, VEL, ACC)
    x.wait_move_done(5.0)
    bus.clock.sleep(0.1)
    assert 1 not in bus._last and bus._home[1] == 0  # home read at start-up, position never
    done = count_commands(net, code)
    inject_at(bus, port, code, Fault("drop", "tx"))
    x.arm_home("limit1", "abrupt") if code == codec.SET_HOMING else x.save_as_home()
    assert done == [1, 0, 0] and bus.stats["verified"] == 1
    st = x.read_status(codec.SEND_POS | codec.SEND_HOME)
    assert st.home_in_progress if code == codec.SET_HOMING else abs(st.home - 1500) <= 3


@pytest.mark.parametrize("fault", [Fault("stall", "rx", duration=0.4), Fault("drop", "rx", count=2)],
                         ids=lambda f: f.describe().replace(" ", "-"))
def test_a_probing_move_whose_reply_was_lost_and_that_touched_before_the_check_is_known_carried_out(fault):
    """A loaded host: the reply to a probing move's LOAD_TRAJ comes too late, and by the time the bus asks the
    module, the probe has touched and the capture has stopped the axis short of its goal. The axis was at rest
    before the command and nothing else moves it, so it moved because the command was carried out: the move is
    not sent again and the touch is reported, not a link fault."""
    net, port, bus, mods = parked()
    x = mods[0]
    starts = count_starts(net)
    x.arm_home("limit1", "abrupt")
    touch_at = PARK[1] + 400

    def probe(network, tick):
        if network.modules[0].pos >= touch_at:
            network.set_inputs(0, limit1=True)

    net.add_tick_hook(probe)
    port.inject(fault)
    x.load_position(PARK[1] + 9000, VEL, ACC)  # START_NOW position move, toward the touch 400 counts ahead
    st = x.wait_move_done(5.0)
    assert starts[0] == 1 and bus.stats["verified"] == 1
    assert not st.home_in_progress and touch_at <= st.position < touch_at + 200
    assert positions_ok(mods[1:], PARK) == []
