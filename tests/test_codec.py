"""Codec byte vectors worked out by hand from the thesis's packet format."""

import pytest

from cmm.nmc import codec as c


def hx(s: str) -> bytes:
    return bytes.fromhex(s)


def test_set_addr_vector_from_thesis():
    # module 0 -> address 1, group 0xFF: checksum 00+21+01+FF = 0x121 -> 0x21
    assert c.set_addr(0x00, 0x01, 0xFF) == hx("AA 00 21 01 FF 21")


def test_set_addr_group_leader_clears_bit7():
    # module 1 becomes leader of group 0x80: group byte 0x00; cksum 01+21+01+00 = 0x23
    assert c.set_addr(0x01, 0x01, 0x80, leader=True) == hx("AA 01 21 01 00 23")
    assert c.set_addr(0x02, 0x02, 0x80) == hx("AA 02 21 02 80 A5")
    with pytest.raises(c.CodecError, match="group address"):
        c.set_addr(1, 1, 0x10)


@pytest.mark.parametrize(
    "packet, expected",
    [
        (c.reset_pos(1), "AA 01 00 01"),
        (c.def_stat(1, 0x09), "AA 01 12 09 1C"),      # position + aux
        (c.read_stat(2, 0x20), "AA 02 13 20 35"),     # module type/version
        (c.start_move(0x80), "AA 80 05 85"),
        (c.io_ctrl(1, 0x0C), "AA 01 18 0C 25"),       # both LIMIT pins inputs
        (c.set_homing(3, 0x11), "AA 03 19 11 2D"),    # LIMIT1 + stop abrupt
        (c.set_baud(0xFF, 10), "AA FF 1A 0A 23"),     # 115200 on the thesis part
        (c.clear_bits(1), "AA 01 0B 0C"),
        (c.save_as_home(0xFF), "AA FF 0C 0B"),
        (c.nop(1), "AA 01 0E 0F"),
        (c.hard_reset(0xFF), "AA FF 0F 0E"),
        (c.stop_motor(1, 0x05), "AA 01 17 05 1D"),    # amp enable + stop abrupt
    ],
)
def test_fixed_command_vectors(packet, expected):
    assert packet == hx(expected)


def test_load_traj_position_velocity_acceleration_start_now():
    # control 0x97 = pos|vel|acc|servo|start; pos 1000 = E8 03 00 00;
    # vel 419430 (25 mm/s at 500 counts/mm) = 0x00066666 -> 66 66 06 00; acc 100 = 64 00 00 00
    pkt = c.load_traj(1, position=1000, velocity=419430, acceleration=100)
    body = hx("01 D4 97 E8 03 00 00 66 66 06 00 64 00 00 00")
    assert pkt == hx("AA") + body + bytes([sum(body) & 0xFF])
    assert c.command_length(pkt[2]) == len(pkt) == 17


def test_load_traj_velocity_mode_reverse_buffered():
    pkt = c.load_traj(2, velocity=65536, acceleration=256, velocity_mode=True, reverse=True, start_now=False)
    assert pkt[2] == 0x94 and pkt[3] == 0x76  # 9 data bytes; vel|acc|servo|velmode|reverse
    lt = c.parse_load_traj(c.decode(pkt).data)
    assert (lt.velocity, lt.acceleration, lt.position, lt.pwm) == (65536, 256, None, None)


def test_load_traj_pwm_mode():
    pkt = c.load_traj(1, pwm=200, servo=False, reverse=True)
    assert pkt == hx("AA 01 24 C8 C8") + bytes([(0x01 + 0x24 + 0xC8 + 0xC8) & 0xFF])


def test_set_gain_fourteen_and_fifteen_bytes():
    g = c.Gains(kp=100, kd=10000, ki=0, il=0, ol=255, cl=0, el=4000, sr=1, db=0)
    pkt = c.set_gain(1, g)
    assert pkt[:3] == hx("AA 01 E6")
    assert pkt[3:17] == hx("64 00 10 27 00 00 00 00 FF 00 A0 0F 01 00")
    assert c.Gains.from_bytes(pkt[3:17]) == g
    g15 = c.Gains.from_bytes(pkt[3:17] + b"\x02")
    assert g15.sm == 2 and c.set_gain(1, g15)[2] == 0xF6
    with pytest.raises(c.CodecError, match="14 data bytes"):
        c.Gains.from_bytes(b"\x00" * 13)
    with pytest.raises(c.CodecError, match="EL"):
        c.Gains(el=0x4000).to_bytes()


def test_stop_here_carries_position():
    assert c.stop_motor(1, c.STOP_HERE | c.AMP_ENABLE, -2) == hx("AA 01 57 11 FE FF FF FF 64")
    with pytest.raises(c.CodecError):
        c.stop_motor(1, c.STOP_HERE)


def test_decode_roundtrip_and_errors():
    pkt = c.load_traj(5, position=-123456, velocity=1, acceleration=2, start_now=False)
    cmd = c.decode(pkt)
    assert (cmd.address, cmd.code, cmd.name) == (5, c.LOAD_TRAJ, "LOAD_TRAJ")
    assert cmd.encode() == pkt
    bad = bytearray(pkt)
    bad[-1] ^= 0xFF
    with pytest.raises(c.ChecksumMismatch):
        c.decode(bad)
    with pytest.raises(c.CodecError, match="announces"):
        c.decode(pkt[:-2] + pkt[-1:])
    assert c.describe(c.nop(3)) == "NOP @ 0x03"


def test_status_parse_every_item_set():
    # status 0x09 (move_done|power_on), position -1, A/D 7, velocity -3, aux 0x0C, home 0x01020304, id type 0 v 3
    raw = hx("09 FF FF FF FF 07 FD FF 0C 04 03 02 01 00 03")
    pkt = raw + bytes([sum(raw) & 0xFF])
    st = c.parse_status(pkt, 0x3F)
    assert (st.status, st.position, st.ad, st.velocity, st.aux, st.home) == (0x09, -1, 7, -3, 0x0C, 0x01020304)
    assert (st.module_type, st.version) == (0, 3)
    assert st.move_done and not st.cksum_error
    assert c.encode_status(0x09, 0x3F, position=-1, ad=7, velocity=-3, aux=0x0C, home=0x01020304, module_id=0x0300) == pkt


@pytest.mark.parametrize("items", range(256))
def test_status_lengths_and_roundtrip_for_any_item_set(items):
    values = dict(position=-5, ad=9, velocity=2, aux=0x14, home=77, module_id=0x0201, position_error=-4, path_points=3)
    pkt = c.encode_status(0x01, items, **values)
    assert len(pkt) == c.status_length(items)
    st = c.parse_status(pkt, items)
    for mask, name, _ in c.STATUS_ITEMS:
        assert getattr(st, name) == (values[name] if items & mask else None)


def test_status_checksum_and_length_errors():
    pkt = bytearray(c.encode_status(0x01, 0x01, position=10))
    with pytest.raises(c.CodecError, match="has 6 bytes"):
        c.parse_status(pkt[:-1], 0x01)
    pkt[2] ^= 1
    with pytest.raises(c.ChecksumMismatch):
        c.parse_status(pkt, 0x01)


def test_fixed_point_conversions_match_doc_example():
    # 25 mm/s at 500 counts/mm, SR 1 -> 6.4 counts/tick -> 419430
    assert c.velocity_to_fixed(25.0, 500) == 419430
    assert c.fixed_to_velocity(419430, 500) == pytest.approx(25.0, rel=1e-6)
    # 100 mm/s^2 at 500 counts/mm: 50000 counts/s^2 * 0.512e-3^2 = 0.0131072 counts/tick^2 -> 859
    assert c.acceleration_to_fixed(100.0, 500) == 859
    assert c.fixed_to_acceleration(859, 500) == pytest.approx(100.0, rel=1e-3)
    assert c.velocity_to_fixed(25.0, 500, sr=2) == 838861
    with pytest.raises(c.CodecError):
        c.velocity_to_fixed(1e9, 500)


def test_baud_tables_per_firmware():
    assert c.baud_divisor(115200) == 10 and c.baud_divisor(19200) == 63
    assert c.baud_divisor(19200, "pic-servo-sc") == 64
    assert c.baud_from_divisor(20) == 57600
    with pytest.raises(c.CodecError, match="not available"):
        c.baud_divisor(38400)


def test_status_words():
    assert c.status_words(0x19, 0x0C) == ["move done", "power on", "position error", "servo on", "accel done"]
