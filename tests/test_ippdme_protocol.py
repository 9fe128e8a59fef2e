"""I++ DME line syntax: what parses, what is refused with which error, how numbers and responses are written."""

from __future__ import annotations

import pytest

from cmm.ippdme.protocol import (ETag, Enum, ParseError, Prop, Text, data_items, error, fmt_number, parse_line,
                                 parse_response)
from cmm.ippdme.errors import IppError


def test_commands_parse_into_name_and_typed_arguments():
    c = parse_line('00012 PtMeas(X(1.33), IJK(0, 0, 1.0),Y( -2.6E01 ), Z(+.5))')
    assert (c.tag, c.name, c.fast) == ("00012", "PtMeas", False)
    assert c.args == (Prop("X", (1.33,)), Prop("IJK", (0.0, 0.0, 1.0)), Prop("Y", (-26.0,)), Prop("Z", (0.5,)))
    assert parse_line('E0005 StopDaemon(E0006)').args == (ETag("E0006"),)
    assert parse_line('00001 SetCoordSystem(PartCsy)').args == (Enum("PartCsy"),)
    assert parse_line('00001 ChangeTool("Probe 1")').args == (Text("Probe 1"),)
    assert parse_line('00270 SetProp (FoundTool.GoToPar.Speed(6.45))').args == (Prop("FoundTool.GoToPar.Speed", (6.45,)),)
    assert parse_line("E0010 GetErrStatusE()").fast and parse_line("E0010 GetErrStatusE()").is_event_tag
    assert parse_line("00001 GetErrorInfo(0513)").args == (513.0,)


@pytest.mark.parametrize("line, tag, number", [
    ("0001 StartSession()", "E0000", 1),  # four-digit tag
    ("00000 StartSession()", "E0000", 1),  # tag 0 is not allowed
    ("A4711 StartSession()", "E0000", 1),
    ("00001StartSession()", "00001", 2),  # no space in column 6
    ("00001 Start\x07Session()", "00001", 7),  # a control character
    ("00001 GoTo(X(1\u00e9))", "00001", 7),  # not 7-bit ASCII
    ("00001 StartSession", "00001", 8),  # no argument list at all
    ("00001 (X(1))", "00001", 8),
    ("00001 GoTo(X(1)", "00001", 502),  # unbalanced
    ("00001 GoTo(X(1)) junk", "00001", 502),
    ("00001 GoTo(X(1),)", "00001", 502),
    ("00001 GoTo(X(+1.2 E2))", "00001", 502),  # NIST numbersErrorCmd: a space inside a number
    ("00001 GoTo(X(12345678901234567))", "00001", 509),  # 17 digits
    ("00001 GoTo(X(-.))", "00001", 509),
    ("00001 GoTo(X(+1.2E0010))", "00001", 509),  # a four-digit exponent
    ("00001 GoTo(X(0.34.33))", "00001", 509),
])
def test_malformed_lines_are_refused_with_the_specs_error(line, tag, number):
    with pytest.raises(ParseError) as info:
        parse_line(line)
    assert (info.value.tag, info.value.error.number) == (tag, number)


def test_numbers_and_responses_are_written_in_the_specs_syntax():
    assert [fmt_number(v) for v in (1.0, -0.0, 2.5e-7, 123.456789, 3, True)] == ["1", "0", "0", "123.456789", "3", "1"]
    line = error("00010", IppError(1008, "GoTo", "X=1e7 is outside the travel"))
    assert line == '00010 ! Error(3, 1008, "GoTo", "Target position out of machine volume")'
    r = parse_response(line)
    assert (r.tag, r.kind, r.severity, r.error_number) == ("00010", "!", 3, 1008)
    assert data_items("X(1), Tool.A(0), IJK(0, 0, 1)") == [("X", [1.0]), ("Tool.A", [0.0]), ("IJK", [0.0, 0.0, 1.0])]
    assert data_items('"Speed", "Number"') == [('"', ["Speed"]), ('"', ["Number"])]
    with pytest.raises(ValueError):
        parse_response("00010 &x")
