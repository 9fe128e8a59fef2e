"""The link's retry rate: a late reply that a retry recovered is counted, not shouted.

On a busy computer a module's reply now and then comes after Kerr's time-out while every axis stands still; the
bus waits longer and sends again (see :mod:`cmm.nmc.bus`), and the reply comes. That is a healthy link: each such
retry is counted (``Bus.stats['late']``, ``['retries']``) and noted in the byte trace, and the operator sees the
counts and rates in Setup > Diagnostics. A link warning (the status bar, the ``link_warning`` event) is raised only
when the retry rate is abnormal:

* at least ``RETRY_WARN_MIN`` retries within the last ``RETRY_WINDOW`` s of link time, and
* those retries are at least ``RETRY_WARN_RATE`` of the transactions in that window.

A reply that is really lost (no answer within the idle patience, or the strict limits during motion) is a link
failure: the machine stops and goes to FAULT, as before. The figures are documented in docs/reliability.md.
"""

from __future__ import annotations

from collections import deque

RETRY_WINDOW = 60.0  # s of link time the rate is taken over
RETRY_WARN_RATE = 0.01  # retried transactions / transactions in the window above which the link is warned about
RETRY_WARN_MIN = 3  # ... and at least this many retries in the window (one slow moment is not a trend)
SNAPSHOT_EVERY = 1.0  # s between the window's snapshots of the counters


class RetryRate:
    """Counters snapshots over a sliding window of the bus clock: the retry rate, cheaply (one deque append a
    second)."""

    def __init__(self) -> None:
        self._snaps: deque[tuple[float, int, int]] = deque()  # (time, transactions, retries)

    def tick(self, now: float, transactions: int, retries: int) -> None:
        if not self._snaps or now - self._snaps[-1][0] >= SNAPSHOT_EVERY:
            self._snaps.append((now, transactions, retries))
        while len(self._snaps) > 1 and now - self._snaps[1][0] >= RETRY_WINDOW:
            self._snaps.popleft()

    def window(self, now: float, transactions: int, retries: int) -> tuple[int, int, float]:
        """(retries, transactions) within the window, and its length in s."""
        self.tick(now, transactions, retries)
        t0, tr0, re0 = self._snaps[0]
        return retries - re0, transactions - tr0, now - t0

    def alarming(self, now: float, transactions: int, retries: int) -> str:
        """A sentence when the retry rate passes the threshold, else ''."""
        n, total, span = self.window(now, transactions, retries)
        if n < RETRY_WARN_MIN or n < RETRY_WARN_RATE * max(total, 1):
            return ""
        return (f"{n} replies in the last {max(span, 1.0):.0f} s came late and were retried "
                f"({n / max(total, 1):.1%} of {total:,} transactions, above the {RETRY_WARN_RATE:.0%} threshold)")


def health_text(stats: dict) -> str:
    """The link's counters for the Diagnostics tab, in words."""
    if not stats:
        return "link counters: not available (the link process did not answer)"
    total = int(stats.get("transactions", 0))
    retries = int(stats.get("retries", 0))
    late = int(stats.get("late", 0))
    wn, wt = int(stats.get("window_retries", 0)), int(stats.get("window_transactions", 0))
    rate = f"{retries / total:.3%}" if total else "-"
    wrate = f"{wn / wt:.3%}" if wt else "-"
    return (f"link counters: {total:,} transactions, {retries:,} retried ({rate}), of them {late:,} late replies "
            f"recovered while standing, {int(stats.get('resyncs', 0)):,} resynchronisations; last "
            f"{RETRY_WINDOW:.0f} s: {wn:,} of {wt:,} retried ({wrate}); the status bar warns above "
            f"{RETRY_WARN_RATE:.0%} with at least {RETRY_WARN_MIN} retries")
