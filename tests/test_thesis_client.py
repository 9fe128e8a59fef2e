"""A host written only from the thesis' byte format (chapter 2), no project imports.

It starts `cmm sim` as a separate process, then initialises the network the
way the thesis describes (16 nulls, SET_ADDR chain, DEF_STAT, SET_GAIN, amp
enable with STOP_MOTOR, LOAD_TRAJ) and moves every module, over TCP and over
the pseudo-terminal, checking the positions read back.
"""

from __future__ import annotations

import os
import re
import select
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.timeout(60)

ROOT = Path(__file__).resolve().parent.parent
# The simulator's default gains (README), as the SET_GAIN data bytes:
# Kp 4000, Kd 10000, Ki 0, IL 0 (int16 LE), OL 255, CL 0, EL 500 (int16 LE), SR 1, DB 0.
GAIN_BYTES = bytes([0xA0, 0x0F, 0x10, 0x27, 0, 0, 0, 0, 0xFF, 0x00, 0xF4, 0x01, 0x01, 0x00])


def checksum(data: bytes) -> int:
    return sum(data) & 0xFF


def packet(address: int, command: int, data: bytes = b"") -> bytes:
    """0xAA, address, command byte (high nibble = data count), data, checksum."""
    body = bytes([address, (len(data) << 4) | command]) + data
    return b"\xAA" + body + bytes([checksum(body)])


class Link:
    """Raw byte pipe over a file descriptor (socket or tty) with a read time-out."""

    def __init__(self, fd: int, send, recv) -> None:
        self.fd, self.send, self.recv = fd, send, recv

    def read(self, n: int, timeout: float = 2.0) -> bytes:
        out = b""
        end = time.monotonic() + timeout
        while len(out) < n:
            left = end - time.monotonic()
            if left <= 0 or not select.select([self.fd], [], [], left)[0]:
                break
            out += self.recv(n - len(out))
        return out

    def flush_input(self) -> None:
        while self.read(256, 0.05):
            pass

    def command(self, address: int, command: int, data: bytes, reply_len: int, timeout: float = 2.0) -> bytes:
        self.send(packet(address, command, data))
        reply = self.read(reply_len, timeout)
        if reply:
            assert len(reply) == reply_len and checksum(reply[:-1]) == reply[-1], reply.hex()
        return reply


def drive(link: Link) -> None:
    link.send(bytes(16))
    time.sleep(0.05)
    link.flush_input()
    n = 0
    while link.command(0x00, 0x1, bytes([n + 1, 0xFF]), 2, timeout=1.5):  # SET_ADDR: 0x21
        n += 1
    assert n == 3
    for addr in range(1, n + 1):
        assert link.command(addr, 0x2, b"\x01", 6)  # DEF_STAT: position
        assert link.command(addr, 0x6, GAIN_BYTES, 6)  # SET_GAIN: 0xE6
        assert link.command(addr, 0x7, b"\x01", 6)  # STOP_MOTOR: amplifier enable
        assert link.command(addr, 0xB, b"", 6)  # CLEAR_BITS
    goals = {addr: 1500 * addr * (-1) ** addr for addr in range(1, n + 1)}
    for addr, goal in goals.items():
        # LOAD_TRAJ 0xD4, control 0x97: position + velocity + acceleration, servo, start now.
        data = bytes([0x97]) + struct.pack("<iII", goal, 6 << 16, 1 << 14)
        assert link.command(addr, 0x4, data, 6)
    for addr, goal in goals.items():
        for _ in range(2000):
            reply = link.command(addr, 0xE, b"", 6)  # NOP
            if reply[0] & 0x01:  # move_done
                break
        assert reply[0] & 0x01
        for _ in range(200):  # the servo settles on the goal (a few ms of the simulator's time)
            reply = link.command(addr, 0xE, b"", 6)
            position = struct.unpack("<i", reply[1:5])[0]
            if abs(position - goal) <= 1:
                break
            time.sleep(0.01)
        assert reply[0] & 0x01 and abs(position - goal) <= 1, (addr, position, goal)


def start_sim(*args: str) -> tuple[subprocess.Popen, str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.Popen(
        [sys.executable, "-c", "import sys; from cmm.cli import main; sys.exit(main(sys.argv[1:]))", "sim", *args],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=ROOT)
    banner = ""
    while "Ctrl-C" not in banner:  # the banner is printed at once; the test time-out guards a hang
        line = proc.stdout.readline()
        if not line:
            break
        banner += line
    assert "Ctrl-C" in banner, banner
    sent = re.search(r"SET_GAIN data bytes: ([0-9a-f ]+)", banner).group(1)
    assert bytes.fromhex(sent) == GAIN_BYTES  # the banner and this client agree
    return proc, banner


def stop_sim(proc: subprocess.Popen) -> None:
    proc.terminate()
    try:
        proc.wait(5)
    except subprocess.TimeoutExpired:
        proc.kill()


def test_thesis_client_over_tcp():
    proc, banner = start_sim("--tcp", "127.0.0.1:0")
    try:
        host, port = re.search(r"socket://([\d.]+):(\d+)", banner).groups()
        with socket.create_connection((host, int(port)), timeout=5) as sock:
            drive(Link(sock.fileno(), sock.sendall, sock.recv))
    finally:
        stop_sim(proc)


@pytest.mark.skipif(sys.platform == "win32", reason="pseudo-terminals are POSIX")
def test_thesis_client_over_pty():
    import termios
    import tty

    proc, banner = start_sim("--pty")
    try:
        device = re.search(r"device (\S+)", banner).group(1)
        fd = os.open(device, os.O_RDWR | os.O_NOCTTY)
        try:
            tty.setraw(fd)
            attrs = termios.tcgetattr(fd)
            attrs[4] = attrs[5] = termios.B19200  # 19200 8N1
            termios.tcsetattr(fd, termios.TCSANOW, attrs)
            drive(Link(fd, lambda b: os.write(fd, b), lambda n: os.read(fd, n)))
        finally:
            os.close(fd)
    finally:
        stop_sim(proc)
