"""Resynchronisation for :class:`~cmm.nmc.bus.Bus`: nulls complete a torn packet and abort a reply in
progress, then a marker (READ_STAT with a reply length no normal reply has) to the module that may owe a late
reply; every byte up to the marker's reply is discarded."""

from __future__ import annotations

from . import codec
from .bus_types import (
    IDLE_PATIENCE, MARKER_ITEMS, MARKER_WAIT, NULLS_RESYNC, OVERSLEPT, PREEMPT_SLICE, QUIET_CONFIRM, RESYNC_WAIT,
    SHORT_MARKER_WAIT, LinkError, ModuleInfo, Preempted,
)


class Resynchronisation:
    """Regaining a clean line after a time-out or a bad reply (a part of :class:`~cmm.nmc.bus.Bus`)."""

    def _resync_patiently(self, address: int | None, since: float) -> None:
        """:meth:`resync`, retried (each a warning) while the machine stands still, until IDLE_PATIENCE s after
        ``since``; a port failure is never retried."""
        while True:
            try:
                self.resync(address)
                return
            except LinkError as exc:
                if self._preempted():
                    raise Preempted(f"a resynchronisation was cut short by a stop ({exc})", address) from exc
                if not self.link_up or not self.still() or self.clock.now() - since >= IDLE_PATIENCE:
                    raise
                # the markers went unanswered too: replies are being lost, not merely late
                self._warn(f"the link did not answer for {self.clock.now() - since:.1f} s ({exc}); retrying")

    def resync(self, address: int | None = None) -> None:
        """Regain the link so that no late reply can be taken for the next one.

        Nulls complete a torn packet (its reply fails its checksum) and abort a
        reply in progress; then a marker to the module that may owe a late
        reply; everything up to the marker's reply is discarded. Without a
        known module: Kerr's quiet wait and flush.
        """
        with self.lock:
            self.stats["resyncs"] += 1
            targets = self._marker_targets(address)
            if not targets:
                self._write(bytes(NULLS_RESYNC))
                self.clock.sleep(RESYNC_WAIT)
                self.flush_input()
                return
            first = targets[0]
            began = self.clock.now()
            self._write(bytes(NULLS_RESYNC), first)
            if self._marker(first, MARKER_WAIT):
                return
            for other in targets[1:2]:  # is it the module or the link?
                self._write(bytes(NULLS_RESYNC), other)
                if self._marker(other, MARKER_WAIT):
                    self._write(bytes(NULLS_RESYNC), first)
                    if self._marker(first, SHORT_MARKER_WAIT):  # the line is clean now: no need to wait long
                        return
                    raise LinkError(f"module {first} stopped answering (module {other} still answers): "
                                    "check its power and cabling", first, self.port_name, module_only=True)
            self._write(bytes(NULLS_RESYNC), first)
            if self._marker(first, MARKER_WAIT):
                return
            raise LinkError(f"no module answers on {self.port_name} any more (no reply for "
                            f"{2 * MARKER_WAIT + (MARKER_WAIT if len(targets) > 1 else 0):.1f} s; "
                            f"{self.heard(began)}): the link is down; check the cable, the adapter and the module "
                            "power", first, self.port_name)

    def _marker_targets(self, address: int | None) -> list[int]:
        known = [m.address for m in self.modules]
        first = self._responder(address) if address is not None else None
        out = [first] if first is not None and first in known else []
        return out + [a for a in known if a not in out]

    def _marker(self, address: int, wait: float, info: ModuleInfo | None = None) -> bool:
        """Send a marker to ``address``; True once its reply has come, last on a quiet line."""
        normal = codec.status_length(self.items.get(address, 0))
        for _ in MARKER_ITEMS:
            items = MARKER_ITEMS[self._marker_turn % len(MARKER_ITEMS)]
            self._marker_turn += 1
            if codec.status_length(items) != normal:
                break
        n = codec.status_length(items)
        if info is None:
            info = next((m for m in self.modules if m.address == address), None)
        self._write(codec.read_stat(address, items), address)
        buf = bytearray()
        sent = self.clock.now()
        away = 0.0  # time this process was off the CPU while waiting: not the link's
        deadline = sent + wait
        while True:
            left = deadline - self.clock.now()
            if left <= 1e-4:  # (a clock that counts whole nanoseconds never reaches a float deadline exactly)
                if buf:
                    self.stats["discarded"] += len(buf)
                return False
            if self._preempted():  # a stop waits for the link: its own stops resynchronise as they go
                return False
            asked = self.clock.now()
            step = min(left, PREEMPT_SLICE)
            chunk = self._read_some(step, address)
            late = self.clock.now() - asked - step
            if late > OVERSLEPT:  # this process was off the CPU meanwhile: that time is not the module's
                deadline += late
                away += late
            if not chunk:
                continue
            buf += chunk
            if not self._is_marker(bytes(buf[-n:]), items, info):
                continue
            self._note_trip(self.clock.now() - sent - away)
            extra = self._read_some(QUIET_CONFIRM, address)
            if extra:  # the marker pattern was not the end: keep reading
                buf += extra
                continue
            stale = len(buf) - n
            self.stats["discarded"] += stale
            if stale:
                self.trace.record(self.clock.now(), "rx", bytes(buf[:stale]),
                                  f"resynchronised on module {address}: {stale} stale bytes discarded")
            return True

    @staticmethod
    def _is_marker(data: bytes, items: int, info: ModuleInfo | None) -> bool:
        try:
            st = codec.parse_status(data, items)
        except codec.CodecError:
            return False
        if st.cksum_error:
            return False
        if info is not None:
            return st.module_type == info.module_type and st.version == info.version
        return True  # while addressing the chain: length, checksum and status are all there is
