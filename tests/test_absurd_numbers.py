"""Non-finite or absurd numbers get a sentence everywhere, with formatted numbers (a move speed of 1e308
was refused as "cannot convert float infinity to integer", a 1e308 target printed a 300-digit number, a DMIS GOTO
to 1e308 overflowed in the motion rails). Through the command API, the page's Go to, DMIS and the command line,
on the in-process simulator (virtual clock). I++ is covered in test_ippdme_handover.py."""

from __future__ import annotations

import re

import pytest
import session_support as sup

from cmm.dmis.executor import DmisError
from cmm.dmis.runner import run_text
from cmm.metrology.numbers_text import num

HEAD = "FILNAM/'x'\nUNITS/MM, ANGRAD\n"
LONG_NUMBER = re.compile(r"\d{12,}")  # no message writes a number with a dozen digits


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    yield from sup.sim_station(tmp_path_factory.mktemp("numbers"), "numbers")


def test_num_formats_what_messages_show():
    assert num(1e308) == "1e+308" and num(235.71234) == "235.712" and num(float("inf")) == "infinite"
    assert num(float("nan")) == "not a number" and num(-5) == "-5.000" and num(5e6) == "5e+06"


@pytest.mark.parametrize("params, words", [
    ({"target": [100, 100, 200], "frame": "machine", "speed": 1e308}, "the speed 1e+308 mm/s is more than"),
    ({"target": [1e308, 100, 200], "frame": "machine"}, "target X=1e+308 mm is outside the travel 0..500 mm"),
    ({"target": [1e308, 100, 200], "frame": "machine", "path": "straight"}, "target X=1e+308 mm is outside"),
    ({"target": [100, 100, 200], "frame": "machine", "speed": float("inf")}, "got infinite mm/s"),
])
def test_a_move_with_an_absurd_number_is_refused_in_one_sentence(station, params, words):
    answer = station.controller.commands.call(None, "move", params, wait=True, timeout=60)
    assert not answer.ok and words in answer.error["message"], answer.error
    assert not LONG_NUMBER.search(answer.error["message"]) and "convert" not in answer.error["message"]


def test_a_probe_with_an_absurd_number_is_refused_in_one_sentence(station):
    api = station.controller.commands
    far = api.call(None, "probe", {"target": [1e308, 100, 20], "approach": [0, 0, -1], "frame": "machine"},
                   wait=True, timeout=60)
    assert not far.ok and "target X=1e+308 mm is outside the travel" in far.error["message"], far.error
    fast = api.call(None, "probe", {"target": [100, 100, 20], "approach": [0, 0, -1], "frame": "machine",
                                    "speed": 1e308}, wait=True, timeout=60)
    assert not fast.ok and "the speed 1e+308 mm/s is more than" in fast.error["message"], fast.error


@pytest.mark.parametrize("body, words", [
    # refused before anything moves, with their line, by the program's check (cmm.dmis.check)
    ("GOTO/1e308, 10, 300\n", "line 3: 1e308 is not a usable number (more than 1e+06 in size)"),
    ("FEDRAT/POSVEL, MMPS, 1e309\n", "is not a finite number"),
    ("V1 = ASSIGN/1e308*10\n", "line 3: 1e308*10 is not a finite number"),
])
def test_dmis_refuses_absurd_numbers_in_words(station, body, words):
    with pytest.raises(DmisError) as err:
        run_text(HEAD + body + "ENDFIL\n", station.controller.commands)
    assert words in str(err.value) and not LONG_NUMBER.search(str(err.value)), str(err.value)


def test_dmis_says_when_a_huge_positioning_speed_is_limited(station):
    result = run_text(HEAD + "FEDRAT/POSVEL, MMPS, 5e5\nGOTO/300, 200, 290\nENDFIL\n", station.controller.commands)
    assert any("mm/s is above the station's positioning speed" in line for line in result.log), result.log


def test_the_page_go_to_with_1e308_is_a_sentence(tmp_path_factory):
    pytest.importorskip("viser")
    import ui_support

    for app in ui_support.station_app(tmp_path_factory, pendant_port=0):
        capp = app.add_client(client_id="operator", is_local=True)
        assert capp.take_control()
        assert capp.go_to(1e308, 100.0, 200.0, frame="Machine") is None
        level, title, body = capp.messages[-1]
        assert (level, title) == ("error", "Go to refused") and "X=1e+308 mm is outside the travel" in body, body
        assert not LONG_NUMBER.search(body)


def test_cmm_run_prints_one_sentence_for_a_1e308_goto(tmp_path, capsys, monkeypatch):
    from cmm.cli import main

    monkeypatch.chdir(tmp_path)  # the run writes its output beside it

    program = tmp_path / "far.dmi"
    program.write_text(HEAD + "GOTO/1e308, 10, 300\nENDFIL\n")
    rc = main(["run", str(program), "--sessions", str(tmp_path / "sessions")])
    err = capsys.readouterr().err
    assert rc != 0 and "line 3: 1e308 is not a usable number (more than 1e+06 in size)" in err, err
    assert "Traceback" not in err and not LONG_NUMBER.search(err)
