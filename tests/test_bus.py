"""The host driver against the simulated network, through real byte streams."""

import pytest

from cmm.nmc import codec
from cmm.nmc.bus import Bus, LinkError, NmcError
from cmm.nmc.module import Module
from cmm.nmc.transport import TransportError
from cmm.sim.network import SimNetwork
from cmm.sim.plant import DEFAULT_GAINS
from cmm.sim.serve import serve_tcp


def ready(bus: Bus) -> list[Module]:
    mods = [Module(bus, m.address) for m in bus.modules]
    for m in mods:
        m.define_status(codec.SEND_POS | codec.SEND_AUX)
        m.set_gains(DEFAULT_GAINS)
        m.clear_bits()
        m.enable()
    return mods


def faulty_bus(transport, seed: int = 1):
    """A 3-module bus behind a FaultyTransport (no faults yet), initialised at 115200, servos on, each module
    asked twice: (port, bus, modules)."""
    from cmm.nmc.faults import FaultyTransport

    port = FaultyTransport(transport, seed=seed)
    bus = Bus(port)
    bus.initialize(115200, expected_modules=3)
    mods = ready(bus)
    for m in mods:
        m.nop()
        m.nop()
    return port, bus, mods


def test_init_discovers_modules_and_changes_baud_in_process():
    net = SimNetwork(3, wire_time=True)
    bus = Bus(net.transport())
    infos = bus.initialize(115200, expected_modules=3)
    assert [i.address for i in infos] == [1, 2, 3]
    assert all(i.module_type == 0 and i.version == net.version for i in infos)
    assert bus.baud == 115200 and all(m.baud == 115200 for m in net.modules)
    sent = bus.trace.entries()
    assert sent[0].data.startswith(bytes(20))  # nulls first, then HARD_RESET to every address
    assert codec.hard_reset(0x80) in sent[0].data and codec.hard_reset(32) in sent[0].data
    assert any(e.data == bytes.fromhex("AA 00 21 01 FF 21") for e in sent)
    assert any(e.data == codec.set_baud(0xFF, 10) for e in sent)
    # re-initialising finds the modules again although they run at 115200 now
    assert len(Bus(net.transport()).initialize(57600)) == 3


def test_init_over_tcp_moves_an_axis():
    net = SimNetwork(3, wire_time=True)
    with serve_tcp(net) as served:
        bus = Bus(served.url)
        try:
            assert len(bus.initialize(115200)) == 3
            x = ready(bus)[0]
            x.load_position(2500, codec.velocity_to_fixed(50, 500), codec.acceleration_to_fixed(500, 500))
            x.wait_move_done(3.0)
            x.bus.clock.sleep(0.05)
            assert abs(x.position() - 2500) <= 1
        finally:
            bus.close()


def test_wrong_module_count_and_wrong_type_are_reported():
    net = SimNetwork(2)
    with pytest.raises(NmcError, match="expected 3 modules on the network, found 2"):
        Bus(net.transport()).initialize(expected_modules=3)
    with pytest.raises(NmcError, match="firmware version"):
        Bus(SimNetwork(1).transport()).initialize(versions=(99,))


def test_silent_module_raises_nmc_error_with_its_address():
    net = SimNetwork(3)
    bus = Bus(net.transport())
    bus.initialize()
    bus._write(codec.hard_reset(2))  # module 2 forgets its address: it stays silent at 2
    bus.clock.sleep(0.01)
    with pytest.raises(LinkError, match=r"module 2 stopped answering \(module 1 still answers\)") as err:
        bus.transact(codec.nop(2))
    assert err.value.address == 2
    assert bus.stats["resyncs"] >= 1
    assert bus.transact(codec.nop(1)) is not None  # the others still answer


def test_garbage_on_the_line_is_recovered_from():
    net = SimNetwork(3)
    bus = Bus(net.transport())
    bus.initialize()
    mods = ready(bus)
    bus._write(bytes([0xAA, 0x02, 0xF4, 0x13]))  # a torn LOAD_TRAJ: the module waits for 15 data bytes
    net.host_in += b"\x5a\xff\x00"  # and noise on the status line
    st = mods[1].nop()  # the first attempt gets garbage or nothing; the bus resynchronises and retries
    assert st.position is not None
    assert bus.stats["resyncs"] >= 1
    assert mods[2].nop().position is not None


class FlakyPort:
    """The in-process transport with one corrupted byte on chosen writes (a noisy command line)."""

    def __init__(self, port, corrupt_writes):
        self.port, self.corrupt, self.writes = port, set(corrupt_writes), 0

    def write(self, data):
        self.writes += 1
        if self.writes in self.corrupt:
            data = data[:-1] + bytes([data[-1] ^ 0x55])
        return self.port.write(data)

    def __getattr__(self, name):
        return getattr(self.port, name)

    def __setattr__(self, name, value):
        if name in ("port", "corrupt", "writes"):
            object.__setattr__(self, name, value)
        else:
            setattr(self.port, name, value)


def test_checksum_error_reply_makes_the_bus_resend_once():
    net = SimNetwork(1)
    port = FlakyPort(net.transport(), ())
    bus = Bus(port)
    bus.initialize()
    (x,) = ready(bus)
    port.corrupt = {port.writes + 1}
    x.load_position(500, codec.velocity_to_fixed(20, 500), codec.acceleration_to_fixed(200, 500))
    assert bus.stats["retries"] == 1
    rx = [e for e in bus.trace.entries() if e.direction == "rx"]
    assert rx[-2].data[0] & codec.CKSUM_ERROR and not rx[-1].data[0] & codec.CKSUM_ERROR
    x.wait_move_done(2.0)
    port.corrupt = {port.writes + 1, port.writes + 2}
    with pytest.raises(NmcError, match="rejected NOP twice with a checksum error"):
        x.nop()


def test_group_start_move_with_leader_and_leaderless():
    net = SimNetwork(3)
    bus = Bus(net.transport())
    bus.initialize()
    mods = ready(bus)
    for m in mods:
        m.set_group(0x80, leader=m.address == 1)
        m.load_position(1000, codec.velocity_to_fixed(20, 500), codec.acceleration_to_fixed(200, 500), start=False)
    bus.clock.sleep(0.05)
    assert all(m.position() == 0 for m in mods)  # buffered, not started
    assert bus.start_move(0x80) is not None  # the leader answers
    bus.clock.sleep(0.1)
    bus.transact(codec.save_as_home(0x80))  # latch all three on one tick
    pos = [m.home_position() for m in mods]
    assert max(pos) - min(pos) <= 2 and pos[0] > 50
    for m in mods:
        m.wait_move_done(2.0)
    # a leaderless group: nobody answers, all start
    for m in mods:
        m.set_group(0x81)
        m.load_position(0, codec.velocity_to_fixed(20, 500), codec.acceleration_to_fixed(200, 500), start=False)
    assert bus.start_move(0x81) is None
    for m in mods:
        m.wait_move_done(2.0)
    assert all(abs(m.position()) <= 1 for m in mods)


def test_module_operations_velocity_pwm_stop_home():
    net = SimNetwork(1)
    bus = Bus(net.transport())
    bus.initialize()
    (x,) = ready(bus)
    x.load_velocity(-codec.velocity_to_fixed(10, 500), codec.acceleration_to_fixed(200, 500))
    bus.clock.sleep(0.3)
    assert x.velocity() == pytest.approx(-10 * 500 * codec.TICK_SECONDS, abs=1)
    x.stop("smooth")
    bus.clock.sleep(0.3)
    assert x.velocity() == 0
    x.arm_home("limit1", "abrupt")
    assert not x.home_captured()
    x.load_velocity(codec.velocity_to_fixed(10, 500), codec.acceleration_to_fixed(200, 500))
    bus.clock.sleep(0.2)
    net.set_inputs(0, limit1=True)
    bus.clock.sleep(0.01)
    assert x.home_captured()
    home = x.home_position()
    bus.clock.sleep(0.1)
    assert abs(x.position() - home) <= 3 and x.velocity() == 0
    x.load_pwm(100)
    bus.clock.sleep(0.1)
    assert not x.aux() & codec.AUX_SERVO_ON
    x.stop("off")
    with pytest.raises(ValueError, match="unknown stop mode"):
        x.stop("sideways")


def test_unknown_port_gives_a_clear_error():
    with pytest.raises(TransportError, match="cannot open serial port '/dev/ttyDOESNOTEXIST'"):
        Bus("/dev/ttyDOESNOTEXIST")
    with pytest.raises(TransportError, match="socket://"):
        Bus("nonsense://x")


def test_byte_trace_records_both_directions():
    net = SimNetwork(1)
    bus = Bus(net.transport())
    bus.initialize()
    bus.trace.clear()
    bus.transact(codec.nop(1))
    tx, rx = bus.trace.entries()
    assert (tx.direction, tx.data, tx.note) == ("tx", codec.nop(1), "NOP @ 0x01")
    assert rx.direction == "rx" and len(rx.data) == 2 and rx.time >= tx.time
    assert "TX AA 01 0E 0F" in bus.trace.dump()
