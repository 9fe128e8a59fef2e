"""Connecting the machine: start the NMC network and every axis (gains, status items, inputs, group, servo
on), restart it after a link failure, and leave the modules in their power-up state on close. A part of
:class:`~cmm.machine.motion.Machine`."""

from __future__ import annotations

import logging
from typing import Any

from ..nmc import codec
from ..nmc.bus import LinkError, ModuleInfo, NmcError
from ..nmc.link_process import open_bus
from ..nmc.module import Module
from .machine_state import GROUP
from .status import MotionError

log = logging.getLogger(__name__)


class Connection:
    """The machine's link to its modules: connect, reconnect, close."""

    def connect(self) -> list[ModuleInfo]:
        """Initialise the network and every axis: gains, status items, inputs, group, servo on."""
        with self._lock:
            self._talked = True
            # a truncated chain (a module that missed its address under load) is retried, not accepted
            infos = self.bus.initialize(self.config.link.baud,
                                        expected_modules=max(a.address for a in self.config.axes))
            found = {m.address for m in infos}
            for axis in self.config.axes:
                if axis.address not in found:
                    raise NmcError(f"axis {axis.name.upper()} expects a module at address {axis.address}, "
                                   f"found modules {sorted(found)}", axis.address)
            for axis, mod in zip(self.config.axes, self.modules):
                self._define_status(axis, mod)
                mod.set_gains(axis.gains)
                mod.plain_inputs()  # probe and home switches are captured, never acted on by the firmware
                mod.clear_bits()
                mod.enable()
                mod.set_group(GROUP, leader=axis.name == "x")
            self.sample()
            return infos

    def _define_status(self, axis: Any, mod: Module) -> None:
        """DEF_STAT with the configured items. If it fails: the firmware, or the link? The status without the
        following error (item 0x40) tells: a module that answers that and refuses the longer one again lacks
        the item; one that answers nothing has a link problem, said as it is (never "needs SC firmware" on SC
        firmware)."""
        try:
            mod.define_status(self.items)
            return
        except NmcError as exc:
            if not self.items & codec.SEND_PERROR:
                raise
            first = exc
        name = f"module {axis.address} ({axis.name.upper()})"
        try:
            mod.define_status(self.items & ~codec.SEND_PERROR)
        except NmcError as exc:
            raise NmcError(f"{name} did not answer while its status items were set up: {first}",
                           axis.address) from exc
        try:
            mod.define_status(self.items)
            return  # it was the link after all, and it answers again
        except NmcError as exc:
            refused = exc
        try:  # so the replies are understood again (the close that follows stops the motors)
            mod.define_status(self.items & ~codec.SEND_PERROR)
        except NmcError:
            pass
        raise NmcError(f"{name} does not answer with the status items the configuration reads (it answers without "
                       "the following error): reading the following error "
                       "(status item 0x40) needs SC firmware. For original PIC-SERVO modules set [link] firmware = "
                       f"\"pic-servo\" and read_following_error = false (the link said: {refused})",
                       axis.address) from refused

    def reconnect(self) -> list[ModuleInfo]:
        """Open the link again and restart the modules (after a link failure); positions are lost."""
        with self._lock:
            try:
                self.bus.close()
            except Exception:  # noqa: BLE001 - it is broken already
                pass
            self.bus = open_bus(self._port, firmware=self.config.link.firmware, trace=self.bus.trace,
                                process=self.config.link.process)
            self.clock = self.bus.clock
            self.modules = [Module(self.bus, a.address) for a in self.config.axes]
            motion, self._motion = self._motion, None
            if motion is not None:
                motion.status.finish(error=MotionError("the link was restarted"))
            return self.connect()

    def close(self) -> None:
        """Stop every axis (motor off), leave the modules in their power-up state and close the port.

        The modules are reset (HARD_RESET to their addresses and groups), so
        the next start-up, this driver's or Kerr's, finds a fresh chain. On a
        dead link nothing is raised: what could not be done is logged.
        """
        self.stop_polling()
        with self._lock:
            motion, self._motion = self._motion, None
            if motion is not None:
                motion.status.finish(error=MotionError("the machine was closed"))
            if not self._talked:  # never started: nothing was commanded, the modules are as they were
                self.bus.close()
                return
            try:
                for mod in self.modules:
                    mod.stop("off")
            except NmcError as exc:
                report = self.bus.stop_all("off")  # never raises
                log.warning("closing the machine: motor off was not confirmed (%s); %s", exc, report.sentence())
            try:
                if not self.bus.link_up:
                    raise LinkError(f"the link {self.bus.port_name} is down")
                self.bus.release()
            except LinkError as exc:
                log.warning("closing the machine: the modules were not reset to their power-up state (%s); the "
                            "next start-up resets them", exc)
            self.bus.close()
