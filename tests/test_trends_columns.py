"""The local trends index's packed chart columns: a chart is the same as the values journalled, in time order, with
parts added since it was packed (also ones measured earlier than the newest), one station's parts, a limit that
changed or is missing, and after it was packed again."""

from __future__ import annotations

import numpy as np

from cmm.session.trends import PACK_AFTER, Measured, Trends

BORE = "bore / diameter"


def _direct(t: Trends, station: str | None = None) -> list[tuple]:
    """The chart's parts straight from the values table (the record), in time order."""
    rows = t.index._q("SELECT v.time, v.value, v.nominal, v.lower, v.upper, p.station, p.run_id, p.serial FROM vals v "
                      "JOIN parts p ON p.seq = v.seq JOIN chars c ON c.id = v.char_id WHERE c.characteristic = ? "
                      "ORDER BY v.time, v.seq", (BORE,))
    return [r for r in rows if station is None or r[5] == station]


def _same(t: Trends, station: str | None = None) -> None:
    h = t.history("bracket", BORE, station)
    want = _direct(t, station)
    assert len(h) == len(want)
    cols = list(zip(*want))
    assert np.array_equal(h.time, np.array(cols[0], float)) and np.array_equal(h.value, np.array(cols[1], float))
    for got, w in zip((h.nominal, h.lower, h.upper), cols[2:5]):
        assert np.array_equal(got, np.array(w, float), equal_nan=True)
    assert h.station == list(cols[5]) and h.run_id == list(cols[6]) and h.serial == list(cols[7])


def test_packed_columns_match_the_journalled_values(tmp_path):
    with Trends(tmp_path / "a", station="cmm-1") as t:
        for i in range(30):  # the limit tightens at part 20; part 7 has no lower limit
            upper = 30.02 if i < 20 else 30.01
            t.record_part("bracket", [Measured(BORE, 30.0 + 0.0005 * i, 30.0, None if i == 7 else 29.98, upper)],
                          serial=f"S{i}", when=1000.0 + 10 * i)
        _same(t)  # packed on this first chart
        # parts since: one measured between two packed ones, others after
        t.record_part("bracket", [Measured(BORE, 30.1, 30.0, 29.98, 30.01)], serial="LATE", when=1055.0)
        for i in range(30, 40):
            t.record_part("bracket", [Measured(BORE, 30.0 + 0.0005 * i, 30.0, 29.98, 30.01)], when=1000.0 + 10 * i)
        _same(t)
        assert t.history("bracket", BORE).serial[6] == "LATE"
        assert t.history("bracket", "no such characteristic").value.size == 0
    # the same folder then taken over by a second station: one station's parts picked from the same columns
    with Trends(tmp_path / "a", station="cmm-2") as t:
        for i in range(PACK_AFTER + 5):  # enough parts since the packing for a chart to pack them again
            t.record_part("bracket", [Measured(BORE, 30.0 + 1e-4 * i, 30.0, 29.98, 30.02)], when=500.0 + i)
        _same(t)
        packed = t.index._q("SELECT upto_seq FROM packed")[0][0]
        t.record_part("bracket", [Measured(BORE, 30.0, 30.0, 29.98, 30.02)], when=2.0)
        _same(t)
        assert t.index._q("SELECT upto_seq FROM packed")[0][0] == packed  # one part since: read beside the pack
        _same(t, "cmm-2")
        _same(t, "cmm-1")
        assert len(t.history("bracket", BORE, "cmm-1")) == 41
        assert len(t.history("bracket", BORE, "cmm-9")) == 0
