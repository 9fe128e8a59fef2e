"""Network start-up for :class:`~cmm.nmc.bus.Bus`: reset at every baud rate, address the chain one module
at a time, check type and version, change the baud rate; release to the power-up state, reopen after a link
error, groups and status items."""

from __future__ import annotations

import serial

from . import codec
from .bus_types import (
    BAUD_SWITCH_WAIT, DISCOVERY_ATTEMPTS, DISCOVERY_WAIT, DISCOVERY_WAITS, IDLE_PATIENCE, MAX_MODULES,
    MAX_REPLY_WAIT, NULLS_INIT, NULLS_RESYNC, LinkError, ModuleInfo, NmcError, reply_timeout,
)
from .transport import open_port


class StartUp:
    """Setting the NMC network up and leaving it (a part of :class:`~cmm.nmc.bus.Bus`)."""

    def _reset_at(self, baud: int) -> None:
        """Nulls and HARD_RESET (no reply) at ``baud`` to every address a module can be reached at.

        A module answers its individual address whatever group it is in, so
        resetting 0..MAX_MODULES and group 0xFF reaches every module this
        driver (or Kerr's library) can have addressed.
        """
        self._set_host_baud(baud)
        burst = bytearray(NULLS_INIT)
        burst += codec.hard_reset(codec.GROUP_ALL) * 2
        for a in range(MAX_MODULES + 1):
            burst += codec.hard_reset(a)
        for g in sorted(set(self.groups.values()) | {0x80}):
            burst += codec.hard_reset(g)
        self._write(bytes(burst))
        self.clock.sleep(0.1)
        self._set_host_baud(codec.POWER_UP_BAUD)
        self.flush_input()

    def _discover(self, expected: int | None = None) -> list[int]:
        """Address the chain one module at a time; each step checked, not assumed. Up to ``expected`` modules
        a missing answer is waited for longer (the chain is known to go on: a slow answer is not its end)."""
        found: list[int] = []
        for addr in range(1, MAX_MODULES + 1):
            waits = DISCOVERY_WAITS if expected is not None and addr <= expected else (DISCOVERY_WAIT, DISCOVERY_WAIT)
            if not self._address_next(addr, found, waits):
                break
            found.append(addr)
            self.items[addr] = 0
        return found

    def _address_next(self, addr: int, found: list[int], waits: tuple[float, ...] = (DISCOVERY_WAIT,) * 2) -> bool:
        """SET_ADDR to the module at 0; a lost reply is told apart from the end of the chain. One try per
        entry of ``waits``: how long the marker waits for a late reply."""
        for wait in waits:
            reply = self._attempt(codec.set_addr(0x00, addr, codec.GROUP_ALL), 0)
            if reply is not None and not reply.cksum_error:
                return True
            if reply is not None:
                continue  # rejected with a checksum error: not carried out
            # no reply: the end of the chain, or a late reply. A marker to the new address tells:
            # a module there took it (and the line is clean once its reply is in).
            self._write(bytes(NULLS_RESYNC))
            if self._marker(addr, wait):
                return True
            self.flush_input()
        return False

    def initialize(
        self,
        baud: int | None = None,
        *,
        expected_modules: int | None = None,
        module_type: int = codec.PIC_SERVO_TYPE,
        versions: tuple[int, ...] | None = None,
    ) -> list[ModuleInfo]:
        """The full NMC start-up: reset, address chain, type check, baud change.

        Works whatever state an earlier run left the modules in (any address,
        group, baud rate, servo on): they are reset at the power-up rate and,
        if the chain is not all there, at every rate the firmware knows.
        Discovery is repeated while it finds fewer modules than expected.
        """
        expected = expected_modules if expected_modules is not None else self.expected_modules
        with self.lock:
            self.link_up = True
            found: list[int] = []
            began = self.clock.now()
            seen: list[int] = []  # modules found by each discovery
            for attempt in range(DISCOVERY_ATTEMPTS):
                self.items.clear()
                self.leaders.clear()
                self._last.clear()
                self._held.clear()
                self._buffered.clear()
                self._armed.clear()
                self._free.clear()
                self._home.clear()
                self._capturing.clear()
                self._before.clear()
                self._calm.clear()
                self.modules = []
                bauds = [codec.POWER_UP_BAUD] if attempt == 0 else [
                    *(b for b in codec.BAUD_DIVISORS[self.firmware] if b != codec.POWER_UP_BAUD), codec.POWER_UP_BAUD]
                for b in bauds:
                    self._reset_at(b)
                self.groups.clear()
                found = self._discover(expected)
                seen.append(len(found))
                self._free.update(found)  # power-up state: PWM mode until a servo command
                if found and (expected is None or len(found) == expected):
                    break
            if not found:
                raise LinkError(f"no PIC-SERVO module answered at address 0 at any baud rate in {len(seen)} "
                                f"attempts over {self.clock.now() - began:.1f} s ({self.heard(began)}): check power, "
                                f"cabling and the port ({self.port_name})", 0, self.port_name)
            if expected is not None and len(found) != expected:
                counts = str(seen[0]) if len(set(seen)) == 1 else f"{', '.join(map(str, seen[:-1]))} and {seen[-1]}"
                raise NmcError(f"expected {expected} modules on the network, found {counts} in {len(seen)} attempts "
                               f"over {self.clock.now() - began:.1f} s: check the address chain (ADDR_IN/ADDR_OUT) "
                               "wiring")
            modules = []
            for addr in found:  # type and version; the home register too (see _check_homing)
                st = self.transact(codec.read_stat(addr, codec.SEND_ID | codec.SEND_HOME),
                                   codec.SEND_ID | codec.SEND_HOME)
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
                since = self.clock.now()
                wait = None
                for tries in range(1, 100):
                    if self._attempt(codec.nop(info.address), items, wait) is not None:
                        break
                    if tries >= 2 and (not self.still() or self.clock.now() - since >= IDLE_PATIENCE):
                        raise LinkError(f"module {info.address} does not answer at {baud} baud after SET_BAUD "
                                        f"({tries} tries in {self.clock.now() - since:.1f} s; "
                                        f"{self.heard(since)})", info.address, self.port_name)
                    self._resync_patiently(info.address, since)
                    wait = min(reply_timeout(codec.status_length(items)) * 2 ** tries, MAX_REPLY_WAIT)

    def release(self) -> None:
        """Leave every module in its power-up state (motor off, address 0, group 0xFF, 19200 baud).

        HARD_RESET goes to each module's individual address and group, so the
        next start-up (this driver's or Kerr's) finds a fresh chain.
        """
        with self.lock:
            burst = bytearray(NULLS_RESYNC)
            for m in reversed(self.modules):
                burst += codec.hard_reset(m.address)
            for g in sorted({codec.GROUP_ALL, *self.groups.values()}):
                burst += codec.hard_reset(g)
            self._write(bytes(burst))
            self.clock.sleep(0.1)
            self._set_host_baud(codec.POWER_UP_BAUD)
            self.flush_input()
            self.modules = []
            self.items.clear()
            self.leaders.clear()
            self.groups.clear()

    def reopen(self) -> list[ModuleInfo]:
        """After a link error: open the port again if it failed, and check every known module still answers.

        The modules keep their addresses, rate and positions (nothing is
        reset); raises :class:`LinkError` if the port or a module stays away.
        """
        with self.lock:
            if isinstance(self._url, str) and not self.link_up:  # the port failed: open it again
                try:
                    self.port.close()
                except (serial.SerialException, OSError):
                    pass
                self.port, self.clock = open_port(self._url, self.baud, reply_timeout(2))
            self.link_up = True
            self._storm = 0
            self.flush_input()
            for info in self.modules:
                self.resync(info.address)
            self._last.clear()
            self._held.clear()
            return list(self.modules)

    def set_group(self, address: int, group: int, *, leader: bool = False) -> None:
        """Put a module in a group (0x80..0xFF); at most one leader per group."""
        with self.lock:
            self.transact(codec.set_addr(address, address, group, leader=leader))
            self.groups[address] = group
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
