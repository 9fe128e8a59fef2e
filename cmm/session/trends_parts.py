"""Who measured each part, by part number, for the trends' chart queries (the local index and the database).

A chart reads its numbers as columns; its parts' station, run id and serial come from this cache, kept as arrays
indexed by the part's number (the journal's sequence number, the database's id), so a chart of 10,000 parts picks
them, and one station's parts, at once instead of part by part. A part's station, run id and serial never change,
so the cache only grows.
"""

from __future__ import annotations

from typing import Any, Iterable

import numpy as np


class PartsCache:
    def __init__(self) -> None:
        self.names: list[str] = []  # station names; codes index them
        self.codes = np.zeros(0, np.int32)  # part number -> station code (-1: not cached)
        self.runs = np.zeros(0, dtype=object)
        self.serials = np.zeros(0, dtype=object)

    @property
    def top(self) -> int:
        """The highest part number the arrays hold."""
        return len(self.codes) - 1

    def add(self, rows: Iterable[tuple[int, str, str, str]]) -> None:
        """Cache (part number, station, run id, serial) rows."""
        rows = list(rows)
        if not rows:
            return
        top = max(int(r[0]) for r in rows)
        if top > self.top:
            grow = top + 1 - len(self.codes)
            self.codes = np.concatenate([self.codes, np.full(grow, -1, np.int32)])
            self.runs = np.concatenate([self.runs, np.full(grow, "", dtype=object)])
            self.serials = np.concatenate([self.serials, np.full(grow, "", dtype=object)])
        index = {name: k for k, name in enumerate(self.names)}
        for q, station, run, serial in rows:
            code = index.get(station)
            if code is None:
                code = index[station] = len(self.names)
                self.names.append(station)
            self.codes[q], self.runs[q], self.serials[q] = code, run, serial

    def missing(self, ids: np.ndarray) -> list[int]:
        """The part numbers of ``ids`` not cached yet."""
        ids = np.asarray(ids, dtype=np.int64)
        if not len(ids):
            return []
        beyond = ids > self.top
        known = ~beyond
        unknown = np.zeros(len(ids), bool)
        unknown[known] = self.codes[ids[known]] < 0
        return sorted(set(ids[beyond | unknown].tolist()))

    def station_mask(self, ids: np.ndarray, station: str) -> np.ndarray:
        code = self.names.index(station) if station in self.names else -2
        return self.codes[np.asarray(ids, dtype=np.int64)] == code

    def who(self, ids: np.ndarray) -> tuple[list[Any], list[Any], list[Any]]:
        """(stations, run ids, serials) of the parts ``ids`` (all cached)."""
        ids = np.asarray(ids, dtype=np.int64)
        names = np.array(self.names + [""], dtype=object)
        return names[self.codes[ids]].tolist(), self.runs[ids].tolist(), self.serials[ids].tolist()
