"""SET_BAUD as hosts written for real modules use it (facts: the PIC-SERVO data sheet, the thesis, Kerr's library).

Facts used here: the module runs at 19200 8N1 after power-up; SET_BAUD takes a
divisor BRD of the module's 20 MHz clock (thesis table 129/63/20/10 for
9600/19200/57600/115200; Kerr's library sends 64/21/10 for 19200/57600/115200);
an addressed SET_BAUD is answered at the old rate, a group one without leader
is not answered; a host must switch its own rate once the command has been sent.
A real UART understands a partner within a few per cent of its rate.
"""

from __future__ import annotations

import sys
import time

import pytest
import serial

from cmm.nmc.transport import open_port

pytestmark = pytest.mark.timeout(60)


def packet(address: int, code: int, data: bytes = b"") -> bytes:
    body = bytes((address, (len(data) << 4) | code)) + data
    return b"\xaa" + body + bytes((sum(body) & 0xFF,))


SET_ADDR, NOP, SET_BAUD = 0x1, 0xE, 0xA


def nop(port, address: int = 1) -> bytes:
    port.reset_input_buffer()
    port.write(packet(address, NOP))
    return port.read(2)


def address_chain(port, n: int) -> None:
    port.write(bytes(20))
    time.sleep(0.01) if not hasattr(port, "sleep") else port.sleep(0.01)
    port.reset_input_buffer()
    for a in range(1, n + 1):
        port.write(packet(0, SET_ADDR, bytes((a, 0xFF))))
        assert len(port.read(2)) == 2, f"module {a} did not take its address"


def group_set_baud_then_switch(port, divisor: int, rate: int, after_s: float, wait=time.sleep) -> None:
    """Kerr's sequence: SET_BAUD to group 0xFF (no reply), switch the host ``after_s`` after sending."""
    port.write(packet(0xFF, SET_BAUD, bytes((divisor,))))
    port.flush()  # tcdrain: returns at once on a pty, after the last bit on a real port
    wait(after_s)
    port.baudrate = rate
    wait(0.02)


@pytest.mark.parametrize("firmware", ["pic-servo", "pic-servo-sc"])
def test_kerr_library_divisors_work_in_process(firmware):
    port, clock = open_port(f"sim://?modules=2&firmware={firmware}", 19200, 0.05)
    address_chain(port, 2)
    for divisor, rate in ((21, 57600), (64, 19200), (10, 115200), (63, 19200), (20, 57600), (129, 9600)):
        group_set_baud_then_switch(port, divisor, rate, 0.001, clock.sleep)
        for a in (1, 2):
            assert len(nop(port, a)) == 2, f"divisor {divisor}: module {a} silent at {rate} baud"
    port.close()


def test_sc_divisor_127_is_9600_and_5_is_230400():
    port, clock = open_port("sim://?modules=1&firmware=pic-servo-sc", 19200, 0.05)
    address_chain(port, 1)
    for divisor, rate in ((127, 9600), (5, 230400), (64, 19200)):
        group_set_baud_then_switch(port, divisor, rate, 0.001, clock.sleep)
        assert len(nop(port)) == 2, f"divisor {divisor}: silent at {rate} baud"
    port.close()


def test_an_unusable_divisor_does_not_brick_the_module():
    """Divisor 30 gives 40.3 kbaud: no PC rate is within a UART's tolerance of it."""
    port, clock = open_port("sim://?modules=1", 19200, 0.05)
    address_chain(port, 1)
    port.write(packet(1, SET_BAUD, bytes((30,))))
    assert len(port.read(2)) == 2  # answered at the old rate
    clock.sleep(0.1)
    assert len(nop(port)) == 2  # still reachable at 19200
    group_set_baud_then_switch(port, 10, 115200, 0.001, clock.sleep)
    assert len(nop(port)) == 2  # and still takes a usable divisor
    port.close()


def test_a_host_that_does_not_switch_loses_the_modules():
    port, clock = open_port("sim://?modules=1", 19200, 0.05)
    address_chain(port, 1)
    port.write(packet(0xFF, SET_BAUD, bytes((21,))))
    clock.sleep(0.1)
    assert nop(port) == b""
    port.close()


@pytest.mark.skipif(sys.platform == "win32", reason="pseudo-terminals are POSIX")
@pytest.mark.parametrize("after_ms", [0, 1, 2])
def test_switching_right_after_the_command_works_on_the_pty(after_ms):
    """Divisor 21 at 19200 -> 57600, then 64 at 57600 -> 19200, the host switching
    ``after_ms`` after the command is sent (as fast hosts on real ports do)."""
    from cmm.sim.network import SimNetwork
    from cmm.sim.serve import serve_pty

    with serve_pty(SimNetwork(2, wire_time=True)) as sim:
        port = serial.Serial(sim.url, 19200, timeout=5.0)  # a reply's wait on a loaded host: a held-up sim thread
        address_chain(port, 2)
        group_set_baud_then_switch(port, 21, 57600, after_ms / 1000)
        assert [len(nop(port, a)) for a in (1, 2)] == [2, 2]
        group_set_baud_then_switch(port, 64, 19200, after_ms / 1000)
        assert [len(nop(port, a)) for a in (1, 2)] == [2, 2]
        port.close()


def test_rfc2217_server_enforces_the_announced_rate():
    """Over RFC 2217 the client announces its rate in the stream: a host that switches right after
    its SET_BAUD works, one that never switches loses the modules (which plain TCP would hide)."""
    from cmm.sim.network import SimNetwork
    from cmm.sim.serve import serve_tcp

    with serve_tcp(SimNetwork(2, wire_time=True), rfc2217=True) as sim:
        assert sim.url.startswith("rfc2217://")
        port = serial.serial_for_url(sim.url, baudrate=19200, timeout=2.0)  # a reply's wait on a loaded host
        address_chain(port, 2)
        port.write(packet(0xFF, SET_BAUD, bytes((21,))))
        port.baudrate = 57600  # announced in order after the command: no wait needed
        time.sleep(0.02)
        assert [len(nop(port, a)) for a in (1, 2)] == [2, 2]
        port.close()
        careless = serial.serial_for_url(sim.url, baudrate=57600, timeout=0.2)
        careless.write(packet(0xFF, SET_BAUD, bytes((10,))))  # to 115200, but the host stays at 57600
        time.sleep(0.1)
        assert nop(careless, 1) == b""
        careless.close()
    with serve_tcp(SimNetwork(1, wire_time=True)) as plain:  # the same careless host passes plain TCP
        port = serial.serial_for_url(plain.url, timeout=2.0)
        address_chain(port, 1)
        port.write(packet(0xFF, SET_BAUD, bytes((10,))))
        time.sleep(0.1)
        assert len(nop(port, 1)) == 2
        port.close()


def test_cmm_sim_rfc2217_serves_the_driver():
    """`cmm sim --rfc2217`: the driver opens rfc2217://, initialises and switches to 115200."""
    import re
    import subprocess

    from cmm.nmc.bus import Bus

    proc = subprocess.Popen([sys.executable, "-m", "cmm.cli", "sim", "--rfc2217", "127.0.0.1:0"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        url = None
        for _ in range(20):
            line = proc.stdout.readline()
            m = re.search(r"rfc2217://\S+", line)
            if m:
                url = m.group(0)
                assert "enforced" in line
                break
        assert url, "cmm sim printed no rfc2217:// URL"
        bus = Bus(url)
        try:
            assert len(bus.initialize(115200)) == 3 and bus.baud == 115200
        finally:
            bus.close()
    finally:
        proc.terminate()
        proc.wait(10)
