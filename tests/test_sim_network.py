"""NMC network rules of the simulator, checked through bytes only."""

from __future__ import annotations

from cmm.nmc import codec as c
from cmm.sim.network import SimNetwork
from test_sim_helpers import ITEMS, Host


def _fresh(n: int = 3, **kw) -> Host:
    host = Host(SimNetwork(n, **kw))
    host.port.write(bytes(16))
    host.port.reset_input_buffer()
    return host


def test_address_chain_answers_one_module_at_a_time():
    host = _fresh(3)
    for addr in (1, 2, 3):
        reply = host.raw(c.set_addr(0, addr), 2)
        assert len(reply) == 2 and reply[1] == reply[0]
    assert host.raw(c.set_addr(0, 4), 2) == b""  # end of chain
    # modules[0] (ADDR_IN grounded) took address 1
    assert [m.address for m in host.net.modules] == [1, 2, 3]
    for addr in (1, 2, 3):
        s = host.cmd(c.read_stat(addr, c.SEND_ID), c.SEND_ID)
        assert s.module_type == 0 and s.version == 4


def test_power_up_state():
    host = _fresh(1)
    host.raw(c.set_addr(0, 1), 2)
    s = host.cmd(c.read_stat(1, 0x3F), 0x3F)  # every item of the original firmware
    assert s.move_done and s.pos_error and not s.home_in_progress
    assert s.position == 0 and s.aux == 0 and s.status & c.POWER_ON
    assert host.cmd(c.nop(1)).status == s.status  # READ_STAT was one-shot: 2-byte reply again


def test_group_leader_replies_members_silent():
    host = _fresh(3)
    host.raw(c.set_addr(0, 1, 0x80, leader=True), 2)
    host.raw(c.set_addr(0, 2, 0x80), 2)
    host.raw(c.set_addr(0, 3, 0x81), 2)
    assert len(host.raw(c.nop(0x80), 8)) == 2  # only the leader
    assert host.raw(c.nop(0x81), 8) == b""  # leaderless group: silent
    # all members executed: DEF_STAT to the group changes every member's reply
    host.raw(c.def_stat(0x80, c.SEND_POS), 20)
    assert len(host.raw(c.nop(2), 20)) == 6
    assert len(host.raw(c.nop(3), 20)) == 2


def test_bad_checksum_not_executed_but_answered():
    host = _fresh(1)
    host.raw(c.set_addr(0, 1), 2)
    bad = bytearray(c.def_stat(1, c.SEND_POS))
    bad[-1] ^= 0x55
    reply = host.raw(bytes(bad), 8)
    assert len(reply) == 2 and reply[0] & c.CKSUM_ERROR  # DEF_STAT not executed
    reply = host.raw(c.nop(1), 8)
    assert len(reply) == 2 and not reply[0] & c.CKSUM_ERROR


def test_leaderless_group_bad_checksum_is_silent():
    host = _fresh(2)
    host.raw(c.set_addr(0, 1), 2)
    host.raw(c.set_addr(0, 2), 2)
    bad = bytearray(c.nop(0xFF))
    bad[-1] ^= 1
    assert host.raw(bytes(bad), 8) == b""


def test_new_command_aborts_pending_reply():
    host = _fresh(1)
    host.raw(c.set_addr(0, 1), 2)
    host.raw(c.def_stat(1, c.SEND_POS), 6)
    host.port.write(c.nop(1))
    host.port.write(c.set_addr(1, 1))  # before the first reply came: it is aborted
    assert host.port.read(20) == bytes(c.encode_status(host.net.modules[0].status_byte(), c.SEND_POS))


def test_new_byte_truncates_reply_on_the_wire():
    host = _fresh(1, wire_time=True)
    host.raw(c.set_addr(0, 1), 2)
    host.raw(c.def_stat(1, 0xFF), 30)
    host.port.write(c.nop(1))
    host.port.sleep(0.004)  # command in, reply partly out
    host.port.write(b"\x00")  # any byte aborts the transmission in progress
    got = host.port.read(50)
    assert 0 < len(got) < c.status_length(0xFF)


def test_incomplete_packet_flushed_by_nulls():
    host = _fresh(1)
    host.raw(c.set_addr(0, 1), 2)
    host.port.write(c.def_stat(1, c.SEND_POS)[:3])  # truncated packet
    # 2 nulls complete it and the checksum fails; the reply reports it
    reply = host.raw(bytes(2), 20)
    assert len(reply) == 2 and reply[0] & c.CKSUM_ERROR
    host.port.write(c.def_stat(1, c.SEND_POS)[:3])
    # the host's 16 flush nulls: the first 2 complete the packet, the rest
    # abort its checksum-error reply before it starts
    assert host.raw(bytes(16), 20) == b""
    assert len(host.raw(c.nop(1), 20)) == 2  # back in sync, DEF_STAT never ran


def test_set_baud_switches_modules():
    host = _fresh(3)
    for a in (1, 2, 3):
        host.raw(c.set_addr(0, a), 2)
    assert host.raw(c.set_baud(0xFF, c.baud_divisor(115200)), 4) == b""
    host.port.sleep(0.1)
    assert host.raw(c.nop(1), 4) == b""  # host still at 19200: nothing understood
    host.port.baudrate = 115200
    for a in (1, 2, 3):
        assert len(host.raw(c.nop(a), 4)) == 2
    assert {m.baud for m in host.net.modules} == {115200}


def test_individual_set_baud_replies_at_old_rate():
    host = _fresh(1)
    host.raw(c.set_addr(0, 1), 2)
    assert len(host.raw(c.set_baud(1, c.baud_divisor(57600)), 4)) == 2
    assert host.raw(c.nop(1), 4) == b""
    host.port.baudrate = 57600
    assert len(host.raw(c.nop(1), 4)) == 2


def test_hard_reset_power_up_state_and_chain_reforms():
    host = Host(SimNetwork(3))
    host.init()
    host.cmd(c.load_traj(2, position=1000, velocity=100000, acceleration=5000))
    host.wait_done(2)
    host.settle()
    assert host.raw(c.hard_reset(0xFF), 20) == b""
    host.port.sleep(0.01)
    assert host.raw(c.nop(1), 20) == b""  # addresses forgotten
    for addr in (1, 2, 3):  # the chain re-forms from modules[0]
        assert len(host.raw(c.set_addr(0, addr), 2)) == 2
    s = host.cmd(c.read_stat(2, 0x3F), 0x3F)
    assert s.position == 0 and s.move_done and s.pos_error and s.aux == 0


def test_wire_time_transaction_duration():
    host = _fresh(1, wire_time=True)
    host.port.baudrate = 19200
    host.raw(c.set_addr(0, 1), 2)
    host.raw(c.def_stat(1, ITEMS), 7)
    t0 = host.port.now()
    assert len(host.raw(c.nop(1), 7)) == 7
    dt = host.port.now() - t0
    wire = 11 * 10 / 19200  # 4 bytes out, 7 back
    assert wire <= dt <= wire + 0.000512 + 1e-6


def test_virtual_transaction_costs_one_tick():
    host = _fresh(1)
    host.raw(c.set_addr(0, 1), 2)
    t0 = host.port.now()
    for _ in range(10):
        host.raw(c.nop(1), 2)
    assert abs(host.port.now() - t0 - 10 * 0.000512) < 1e-9


def test_transport_pyserial_subset_and_virtual_clock():
    net = SimNetwork(1)
    port = net.transport(timeout=0.25)
    assert port.is_open and port.baudrate == 19200 and port.now() == 0.0
    assert port.read(1) == b"" and abs(port.now() - 0.25) < 1e-6  # the whole time-out passes
    port.sleep(0.75)
    assert abs(port.now() - 1.0) < 1e-6
    port.write(c.set_addr(0, 1))
    port.flush()
    assert port.in_waiting == 0  # executes at the end of the tick
    assert len(port.read(2)) == 2 and port.in_waiting == 0
    port.write(c.nop(1))
    port.sleep(0.001)
    assert port.in_waiting == 2
    port.reset_input_buffer()
    port.reset_output_buffer()
    assert port.in_waiting == 0
    port.close()
    assert not port.is_open


def test_idle_skip_is_exact():
    """A tick hook disables the idle fast path; results must not change."""
    def run(hook: bool) -> tuple:
        net = SimNetwork(2)
        if hook:
            net.add_tick_hook(lambda network, tick: None)
        host = Host(net)
        host.init()
        host.cmd(c.load_traj(1, position=3001, velocity=300000, acceleration=4000))
        host.port.sleep(0.5)
        host.cmd(c.load_traj(2, position=-77, velocity=300000, acceleration=4000))
        host.port.sleep(1.0)
        return tuple((p.x, p.v, p.count) for p in net.plants) + (net.tick, net.now_ns)

    assert run(False) == run(True)


def test_realtime_in_process_clock():
    net = SimNetwork(1, realtime=True)
    port = net.transport(timeout=0.05)
    port.write(c.set_addr(0, 1))
    assert len(port.read(2)) == 2
    t0 = port.now()
    assert port.read(1) == b""
    assert port.now() - t0 >= 0.05
