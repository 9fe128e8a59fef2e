"""The NMC bus: one command, one reply, over any byte transport.

Rules from the protocol (shared/docs/picservo-nmc.md):
- the host sends one command and waits for its status packet before the next;
- read timeout 50 ms + 2 ms per expected byte (Kerr's library);
- a reply with cksum_error set means the module ignored the command: resend once;
- after a timeout or garbage, resynchronise: nulls, wait, flush, NOP each module;
- group commands are answered by the group leader only, or not at all.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

from . import codec
from .trace import ByteTrace
from .transport import open_port


class NmcError(Exception):
    """A failure on the NMC network, naming the module address when there is one."""

    def __init__(self, message: str, address: int | None = None) -> None:
        super().__init__(message)
        self.address = address


@dataclass(frozen=True)
class ModuleInfo:
    address: int
    module_type: int
    version: int


NULLS_INIT = 20  # the thesis sends 16, Kerr's library 20
NULLS_RESYNC = 30
RESYNC_WAIT = 0.1
BAUD_SWITCH_WAIT = 0.1
LEADERLESS_WAIT = 0.002  # at least one servo tick before the next command (several at SR > 1)
MAX_MODULES = 32


def reply_timeout(n_bytes: int) -> float:
    return 0.050 + 0.002 * n_bytes


class Bus:
    """An NMC network behind one serial port.

    ``port`` is a pyserial URL or device name, or an in-process transport
    (the simulator's) with the same byte interface. Thread-safe: transactions
    are serialised.
    """

    def __init__(self, port: Any, *, firmware: str = "pic-servo", trace: ByteTrace | None = None) -> None:
        self.firmware = firmware
        self.baud = codec.POWER_UP_BAUD
        self.port, self.clock = open_port(port, self.baud, reply_timeout(2))
        self.trace = trace if trace is not None else ByteTrace()
        self.lock = threading.RLock()
        self.items: dict[int, int] = {}  # address -> DEF_STAT items the module sends
        self.leaders: dict[int, int] = {}  # group address -> leader's individual address
        self.modules: list[ModuleInfo] = []
        self.stats = {"transactions": 0, "retries": 0, "resyncs": 0}

    # --- low level ------------------------------------------------------

    def close(self) -> None:
        with self.lock:
            self.port.close()

    def _write(self, data: bytes) -> None:
        self.trace.tx(self.clock.now(), data)
        self.port.write(data)

    def _read(self, n: int) -> bytes:
        timeout = reply_timeout(n)
        if self.port.timeout != timeout:
            self.port.timeout = timeout
        data = self.port.read(n)
        if data:
            self.trace.rx(self.clock.now(), data, "" if len(data) == n else f"short reply: {len(data)} of {n} bytes")
        return data

    def _set_host_baud(self, baud: int) -> None:
        self.port.baudrate = baud
        self.baud = baud

    def flush_input(self) -> None:
        self.port.reset_input_buffer()

    def _attempt(self, packet: bytes, items: int) -> codec.Status | None:
        """Send once; the parsed reply, or None on timeout / garbage."""
        self._write(packet)
        n = codec.status_length(items)
        data = self._read(n)
        if len(data) != n:
            return None
        try:
            return codec.parse_status(data, items)
        except codec.CodecError:
            return None

    def _reply_items(self, address: int) -> int | None:
        """Items in the reply to a command sent to ``address``; None if nobody replies."""
        if address in self.items:
            return self.items[address]
        if address >= 0x80 and address in self.leaders:
            return self.items.get(self.leaders[address], 0)
        if address >= 0x80:
            return None
        return 0

    def transact(self, packet: bytes, items: int | None = None) -> codec.Status | None:
        """Send a command packet and return the parsed status reply.

        ``items`` overrides the expected status items (READ_STAT). Group
        commands to a group without a leader return None after a short wait.
        """
        address = packet[1]
        with self.lock:
            expected = self._reply_items(address) if items is None else items
            self.stats["transactions"] += 1
            if expected is None:  # leaderless group: nobody answers
                self._write(packet)
                self.clock.sleep(LEADERLESS_WAIT)
                return None
            for attempt in range(2):
                status = self._attempt(packet, expected)
                if status is not None and not status.cksum_error:
                    return status
                self.stats["retries"] += 1
                if status is None:
                    self.resync(exclude=address)
            who = f"module {address}" if address < 0x80 else f"group {address:#04x} leader"
            name = codec.COMMAND_NAMES[packet[2] & 0x0F]
            if status is not None:
                raise NmcError(f"{who} rejected {name} twice with a checksum error: check the wiring and the baud rate", address)
            raise NmcError(
                f"{who} did not answer {name} at {self.baud} baud after a resynchronisation: "
                "check its power, cabling and address",
                address,
            )

    def resync(self, exclude: int | None = None) -> None:
        """Regain the link: nulls complete any partial packet, then wait, flush, NOP each module."""
        with self.lock:
            self.stats["resyncs"] += 1
            self._write(bytes(NULLS_RESYNC))
            self.clock.sleep(RESYNC_WAIT)
            self.flush_input()
            for info in self.modules:
                if info.address == exclude:
                    continue
                items = self.items.get(info.address, 0)
                if self._attempt(codec.nop(info.address), items) is None:
                    self.clock.sleep(RESYNC_WAIT)
                    self.flush_input()
                    if self._attempt(codec.nop(info.address), items) is None:
                        raise NmcError(
                            f"module {info.address} stays silent after resynchronisation: check its power and cabling",
                            info.address,
                        )

    # --- network set-up ---------------------------------------------------

    def _reset_at(self, baud: int) -> None:
        """Nulls and HARD_RESET to every module at ``baud`` (no reply), then back to power-up rate."""
        self._set_host_baud(baud)
        self._write(bytes(NULLS_INIT))
        self.clock.sleep(0.01)
        for _ in range(2):
            self._write(codec.hard_reset(codec.GROUP_ALL))
            self.clock.sleep(0.01)
        self.clock.sleep(0.1)
        self._set_host_baud(codec.POWER_UP_BAUD)
        self.flush_input()

    def _discover(self) -> list[int]:
        found: list[int] = []
        for addr in range(1, MAX_MODULES + 1):
            reply = self._attempt(codec.set_addr(0x00, addr, codec.GROUP_ALL), 0)
            if reply is None:
                self.flush_input()
                break
            found.append(addr)
            self.items[addr] = 0
        return found

    def initialize(
        self,
        baud: int | None = None,
        *,
        expected_modules: int | None = None,
        module_type: int = codec.PIC_SERVO_TYPE,
        versions: tuple[int, ...] | None = None,
    ) -> list[ModuleInfo]:
        """The full NMC start-up: reset, address chain, type check, baud change.

        Modules left at another rate by an earlier run are reset at every rate
        the firmware knows before the chain is addressed.
        """
        with self.lock:
            self.items.clear()
            self.leaders.clear()
            self.modules = []
            self._reset_at(codec.POWER_UP_BAUD)
            found = self._discover()
            if not found:
                for other in codec.BAUD_DIVISORS[self.firmware]:
                    if other != codec.POWER_UP_BAUD:
                        self._reset_at(other)
                found = self._discover()
            if not found:
                raise NmcError("no PIC-SERVO module answered at address 0: check power, cabling and the port", 0)
            if expected_modules is not None and len(found) != expected_modules:
                raise NmcError(f"expected {expected_modules} modules on the network, found {len(found)}")
            modules = []
            for addr in found:
                st = self.transact(codec.read_stat(addr, codec.SEND_ID), codec.SEND_ID)
                assert st is not None
                if st.module_type != module_type:
                    raise NmcError(f"module {addr} is of type {st.module_type}, expected {module_type} (PIC-SERVO)", addr)
                if versions is not None and st.version not in versions:
                    raise NmcError(f"module {addr} has firmware version {st.version}, expected one of {versions}", addr)
                modules.append(ModuleInfo(addr, st.module_type, st.version))
            self.modules = modules
            if baud is not None and baud != self.baud:
                self.change_baud(baud)
            return list(modules)

    def change_baud(self, baud: int) -> None:
        """SET_BAUD to every module (group 0xFF, no leader), switch the host, verify each module."""
        divisor = codec.baud_divisor(baud, self.firmware)
        with self.lock:
            self._write(codec.set_baud(codec.GROUP_ALL, divisor))
            self.clock.sleep(BAUD_SWITCH_WAIT)
            self._set_host_baud(baud)
            self.flush_input()
            for info in self.modules:
                items = self.items.get(info.address, 0)
                if self._attempt(codec.nop(info.address), items) is None:
                    raise NmcError(f"module {info.address} does not answer at {baud} baud after SET_BAUD", info.address)

    def set_group(self, address: int, group: int, *, leader: bool = False) -> None:
        """Put a module in a group (0x80..0xFF); at most one leader per group."""
        with self.lock:
            self.transact(codec.set_addr(address, address, group, leader=leader))
            for g, a in list(self.leaders.items()):
                if a == address:
                    del self.leaders[g]
            if leader:
                self.leaders[group] = address

    def define_status(self, address: int, items: int) -> codec.Status | None:
        """DEF_STAT: the reply to this command already carries the new items."""
        with self.lock:
            status = self.transact(codec.def_stat(address, items), items if address < 0x80 else None)
            targets = [address] if address < 0x80 else [m.address for m in self.modules]
            for a in targets:
                self.items[a] = items
            return status

    def group(self, group: int, packet_builder) -> codec.Status | None:
        """Send ``packet_builder(group)`` to a group; the leader's reply, or None."""
        return self.transact(packet_builder(group))

    def start_move(self, group: int = codec.GROUP_ALL) -> codec.Status | None:
        """START_MOVE to a group: every member starts on the same servo tick."""
        return self.transact(codec.start_move(group))
