"""Bytes on the port for :class:`~cmm.nmc.bus.Bus`: writing a packet, reading a reply within its time-out
(never passing over bytes already in the buffer; a descheduled host gets the reply's time again), one attempt
at a command, the link's round trip and its warnings. Every pyserial failure becomes a :class:`LinkError`."""

from __future__ import annotations

import serial

from . import codec
from .bus_types import (
    MARKER_WAIT, OVERSLEPT, OVERSLEPT_EXTENSIONS, REPLY_ROUND_TRIPS, TRIP_HALF_LIFE, LinkError, reply_timeout,
)


class Framing:
    """Port I/O of the bus: packets out, replies in, one attempt at a time (a part of :class:`~cmm.nmc.bus.Bus`)."""

    def _link_error(self, doing: str, exc: BaseException, address: int | None = None) -> LinkError:
        self.link_up = False
        who = f" (module {address})" if address is not None and address < 0x80 else (
            f" (group {address:#04x})" if address is not None else "")
        return LinkError(f"the serial link {self.port_name} failed while {doing}{who}: {exc or type(exc).__name__}. "
                         "Check the cable, the adapter and the module power, then reconnect", address, self.port_name)

    def close(self, *, release: bool = False) -> None:
        """Close the port; with ``release`` first leave the modules in their power-up state."""
        with self.lock:
            if release and self.link_up:
                try:
                    self.release()
                except LinkError:
                    pass
            try:
                self.port.close()
            except (serial.SerialException, OSError):
                pass
            self.link_up = False

    def _write(self, data: bytes, address: int | None = None) -> None:
        self.trace.tx(self.clock.now(), data)
        try:
            self.port.write(data)
        except (serial.SerialException, OSError) as exc:
            raise self._link_error("sending", exc, address) from exc

    def _set_timeout(self, timeout: float | None, address: int | None = None) -> None:
        try:
            if self.port.timeout != timeout:
                self.port.timeout = timeout
        except (serial.SerialException, OSError, ValueError) as exc:
            raise self._link_error("setting the read time-out", exc, address) from exc

    def _read(self, n: int, address: int | None = None, timeout: float | None = None,
              since: float | None = None) -> bytes:
        """Up to ``n`` bytes of a reply, waiting ``timeout`` (default Kerr's) from ``since`` (the moment the
        request left; default now). A reply torn across the deadline (the host was descheduled between two
        chunks: pyserial then returns what it had) is completed from the bytes already in the port's buffer:
        a reply that has arrived is never declared timed out."""
        wait = reply_timeout(n) if timeout is None else timeout
        start = self.clock.now() if since is None else since
        self._set_timeout(wait, address)  # (the same value every time: a real port is not reconfigured)
        renewed = 0
        try:
            data = self.port.read(n)
            while len(data) < n:
                left = start + wait - self.clock.now()
                if left > 1e-4:  # pyserial gave up early (a chunk came just before its own deadline)
                    self._set_timeout(left, address)
                    more = self.port.read(n - len(data))
                    if more:
                        data += more
                        continue
                waiting = self.port.in_waiting
                more = self.port.read(min(waiting, n - len(data))) if waiting else b""  # already here: no wait
                if more:
                    data += more
                    continue
                if self.clock.now() - (start + wait) > OVERSLEPT and renewed < OVERSLEPT_EXTENSIONS:
                    # this process was off the CPU well past the deadline (the read came back late): the time it
                    # was away is not the module's; it gets its reply time again, counted from now
                    renewed += 1
                    start = self.clock.now()
                    continue
                break
        except (serial.SerialException, OSError) as exc:
            raise self._link_error("waiting for a reply", exc, address) from exc
        if data:
            self._heard.append((self.clock.now(), bytes(data)))
            self.trace.rx(self.clock.now(), data, "" if len(data) == n else f"short reply: {len(data)} of {n} bytes")
        return data

    def heard(self, since: float | None = None) -> str:
        """What came in since ``since`` (bus clock), in words for an error message."""
        chunks = [d for t, d in self._heard if since is None or t >= since]
        data = b"".join(chunks)
        if not data:
            return "nothing was received"
        shown = data[-24:].hex(" ")
        return (f"received {len(data)} byte{'s' if len(data) != 1 else ''} in {len(chunks)} "
                f"piece{'s' if len(chunks) != 1 else ''} ({'... ' if len(data) > 24 else ''}{shown})")

    def _late(self, text: str) -> None:
        """A late reply being retried while all stands still: counted and traced; a link warning only when the
        retry rate passes its threshold (see :mod:`cmm.nmc.link_health`)."""
        self.stats["late"] += 1
        self.trace.record(self.clock.now(), "rx", b"", f"late: {text}")
        alarm = self._rate.alarming(self.clock.now(), self.stats["transactions"], self.stats["retries"])
        if alarm:
            self._warn(f"{alarm}; last: {text}")

    def _count_window(self) -> None:
        n, total, _ = self._rate.window(self.clock.now(), self.stats["transactions"], self.stats["retries"])
        self.stats["window_retries"], self.stats["window_transactions"] = n, total

    def _warn(self, text: str) -> None:
        """A link warning: shown to the operator (the control state), nothing is stopped for it."""
        self.warning = (self.warning[0] + 1, text, self.clock.now())
        self.trace.record(self.clock.now(), "rx", b"", f"warning: {text}")

    def _waiting(self, address: int | None = None) -> int:
        try:
            return int(self.port.in_waiting)
        except (serial.SerialException, OSError) as exc:
            raise self._link_error("reading the port", exc, address) from exc

    def _read_some(self, timeout: float, address: int | None = None) -> bytes:
        """Whatever arrives within ``timeout``: waits for one byte, then takes what is there."""
        self._set_timeout(max(timeout, 0.0), address)
        try:
            data = self.port.read(1)
            if data:
                n = self.port.in_waiting
                if n:
                    data += self.port.read(n)
        except (serial.SerialException, OSError) as exc:
            raise self._link_error("waiting for a reply", exc, address) from exc
        if data:
            self._heard.append((self.clock.now(), bytes(data)))
        return data

    def _set_host_baud(self, baud: int) -> None:
        try:
            self.port.baudrate = baud
        except (serial.SerialException, OSError, ValueError) as exc:
            raise self._link_error(f"switching the port to {baud} baud", exc) from exc
        self.baud = baud

    def flush_input(self) -> None:
        try:
            self.port.reset_input_buffer()
        except (serial.SerialException, OSError) as exc:
            raise self._link_error("flushing the input", exc) from exc

    def _discard_stale(self, address: int | None) -> None:
        """Bytes waiting before a command are late or noise: never part of the coming reply."""
        n = self._waiting(address)
        if n:
            try:
                data = self.port.read(n)
            except (serial.SerialException, OSError) as exc:
                raise self._link_error("reading the port", exc, address) from exc
            self.stats["discarded"] += len(data)
            self._heard.append((self.clock.now(), bytes(data)))
            self.trace.rx(self.clock.now(), data, "stale bytes discarded")

    # --- one transaction ----------------------------------------------------------

    def _attempt(self, packet: bytes, items: int, wait: float | None = None) -> codec.Status | None:
        """Send once; the parsed reply, or None on time-out, garbage or surplus bytes. ``wait``: how long the
        reply may take (default Kerr's 50 ms + 2 ms per byte), counted from the moment the request left."""
        address = packet[1]
        self._discard_stale(address)
        self._sent_at = self.clock.now()
        self._write(packet, address)
        n = codec.status_length(items)
        data = self._read(n, address, self._reply_wait(items) if wait is None else wait, since=self.clock.now())
        if len(data) != n:
            return None
        self._note_trip(self.clock.now() - self._sent_at)
        try:
            status = codec.parse_status(data, items)
        except codec.CodecError:
            return None
        if self._waiting(address):  # more bytes than a reply: something else got mixed in
            self.stats["suspect"] += 1
            return None
        return status

    def _recent_trip(self) -> float:
        """The link's recent round trip: the largest seen, halved for every TRIP_HALF_LIFE s since."""
        return self._trip * 0.5 ** (max(self.clock.now() - self._trip_at, 0.0) / TRIP_HALF_LIFE)

    def _note_trip(self, seconds: float) -> None:
        """A round trip just seen (request sent to reply read)."""
        if seconds >= self._recent_trip():
            self._trip, self._trip_at = seconds, self.clock.now()

    def _reply_wait(self, items: int) -> float:
        """How long a reply of ``items`` may take now (see REPLY_ROUND_TRIPS)."""
        kerr = reply_timeout(codec.status_length(items))
        if not self.local:
            return kerr
        return min(max(kerr, REPLY_ROUND_TRIPS * self._recent_trip()), MARKER_WAIT)
