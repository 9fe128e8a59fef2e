"""`cmm sessions` and `cmm report` on a recorded session."""

from __future__ import annotations

import csv
import json

import pytest

import session_support as sup
from cmm.cli import main
from cmm.journal.writer import Journal


@pytest.fixture
def store(tmp_path):
    sup.recorded_copy(tmp_path / "sessions")
    return tmp_path / "sessions"


def test_list_show_rename_delete(store, capsys):
    assert main(["sessions", "--store", str(store), "list"]) == 0
    assert "taught" in capsys.readouterr().out
    assert main(["sessions", "--store", str(store), "show", "taught"]) == 0
    out = capsys.readouterr().out
    assert "features: 3" in out and "'boss': cylinder/ls, 8 hits" in out
    assert main(["sessions", "--store", str(store), "rename", "taught", "first part"]) == 0
    assert (store / "first part.jsonl").exists() and not (store / "taught.jsonl").exists()
    assert main(["sessions", "--store", str(store), "rename", "missing", "x"]) == 1
    assert "there is no session 'missing'" in capsys.readouterr().err
    assert main(["sessions", "--store", str(store), "rename", "first part", "../escape"]) == 1
    assert "not a usable session name" in capsys.readouterr().err
    with Journal(store / "first part.jsonl"):  # being recorded
        assert main(["sessions", "--store", str(store), "delete", "first part", "--yes"]) == 1
        assert "being recorded" in capsys.readouterr().err
        main(["sessions", "--store", str(store), "list"])
        assert "(recording)" in capsys.readouterr().out
    assert main(["sessions", "--store", str(store), "delete", "first part"]) == 1  # no terminal, no --yes
    assert "--yes" in capsys.readouterr().err
    assert main(["sessions", "--store", str(store), "delete", "first part", "--yes"]) == 0
    assert list(store.glob("*.jsonl")) == []


def test_export_csv_and_json(store, tmp_path, capsys):
    out_csv, out_json = tmp_path / "hits.csv", tmp_path / "session.json"
    assert main(["sessions", "--store", str(store), "export", "taught", "--csv", str(out_csv), "--json", str(out_json)]) == 0
    rows = list(csv.DictReader(out_csv.open()))
    assert len(rows) == 26 and rows[0]["id"] == "1"
    assert set(rows[0]) >= {"counts_x", "counts_y", "counts_z", "machine_x", "approach_z", "speed", "time",
                            "point_x", "deviation"}
    assert all(abs(float(r["deviation"])) < 0.005 for r in rows)  # the sample part was found by its hash
    data = json.loads(out_json.read_text())
    assert data["session"]["name"] == "taught" and len(data["events"]) == data["session"]["events"]
    assert len(data["hits"]) == 26 and len(data["features"]) == 3 and data["part"]["sha256"]
    assert main(["sessions", "--store", str(store), "export", "taught"]) == 2


def test_reevaluate_and_teach_commands(store, tmp_path, capsys):
    assert main(["sessions", "--store", str(store), "reevaluate", "taught", "taught r1.1", "--tip-radius", "1.1"]) == 0
    assert (store / "taught r1.1.jsonl").exists()
    assert main(["sessions", "--store", str(store), "teach", "taught", "-o", str(tmp_path / "p.toml")]) == 0
    assert "[[hits]]" in (tmp_path / "p.toml").read_text()


def test_report_command(store, tmp_path, capsys):
    out = tmp_path / "report.html"
    assert main(["report", "taught", "--store", str(store), "-o", str(out)]) == 0
    text = out.read_text()
    for name in ("top_plane", "boss", "dome"):
        assert name in text
    assert main(["report", str(store / "taught.jsonl"), "-o", str(out)]) == 0  # a journal path works too
    assert main(["report", "nope", "--store", str(store), "-o", str(out)]) == 1
    assert "there is no session 'nope'" in capsys.readouterr().err
    # the colour map's bands and reach
    assert main(["report", "taught", "--store", str(store), "-o", str(out), "--map-tolerance", "0.004",
                 "--warning", "75", "--reach", "30"]) == 0
    text = out.read_text()
    assert "&gt; +4 µm out of tolerance" in text and "+3 .. +4 µm warning" in text and "no hit within 30 mm" in text
    assert text.count('class="map"') == 3  # top, front and isometric map views
    assert main(["report", "taught", "--store", str(store), "-o", str(out), "--warning", "0"]) == 2
    assert "warning limit must be a fraction" in capsys.readouterr().err
