"""`cmm deviation` end to end through the dispatcher."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from cmm.cli import main
from cmm.metrology.pointfile import PointFileError, parse_points


@pytest.fixture()
def box_stl(tmp_path):
    path = tmp_path / "box.stl"
    trimesh.creation.box(bounds=((0, 0, 0), (100, 50, 20))).export(path)
    return path


def _points_file(tmp_path, text):
    path = tmp_path / "points.txt"
    path.write_text(text)
    return path


def test_table_output(tmp_path, box_stl, capsys):
    pts = _points_file(tmp_path, "x,y,z\n# probe run 1\n50, 25, 20.012\n\n10 10 19.995   # low spot\n")
    assert main(["deviation", str(box_stl), str(pts)]) == 0
    out = capsys.readouterr().out
    assert "+ = point outside the nominal material" in out
    assert "+0.012000" in out and "-0.005000" in out
    assert "n=2" in out and "max=+0.012000" in out and "min=-0.005000" in out


def test_json_output_with_pose(tmp_path, box_stl, capsys):
    pose = np.eye(4)
    pose[:3, 3] = (1000.0, 200.0, -50.0)
    pose_file = tmp_path / "pose.txt"
    pose_file.write_text("\n".join(" ".join(str(v) for v in row) for row in pose))
    pts = _points_file(tmp_path, "1050 225 -29.9\n1010 225 -40\n")
    assert main(["deviation", str(box_stl), str(pts), "--pose", str(pose_file), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["sign_convention"].startswith("deviation = signed distance")
    devs = [p["deviation"] for p in data["points"]]
    np.testing.assert_allclose(devs, [0.1, -10.0], atol=1e-9)
    assert data["summary"]["n"] == 2
    assert data["summary"]["rms"] == pytest.approx(np.sqrt((0.01 + 100.0) / 2))


def test_malformed_line_names_line_number(tmp_path, box_stl, capsys):
    pts = _points_file(tmp_path, "x y z\n1 2 3\n4 five 6\n")
    assert main(["deviation", str(box_stl), str(pts)]) == 1
    err = capsys.readouterr().err
    assert "line 3" in err and "five" in err


def test_wrong_column_count():
    with pytest.raises(PointFileError, match="line 2: expected 3 finite numbers"):
        parse_points("1 2 3\n1 2\n".splitlines())
    with pytest.raises(PointFileError, match="line 1: expected 3 finite numbers"):
        parse_points(["1 nan 3"])


def test_mesh_errors_go_to_stderr(tmp_path, capsys):
    pts = _points_file(tmp_path, "1 2 3\n")
    assert main(["deviation", str(tmp_path / "part.x_t"), str(pts)]) == 1
    captured = capsys.readouterr()
    assert "unsupported mesh format" in captured.err and captured.out == ""
    assert main(["deviation", str(tmp_path / "missing.stl"), str(pts)]) == 1
    assert "does not exist" in capsys.readouterr().err


def test_missing_points_file(tmp_path, box_stl, capsys):
    assert main(["deviation", str(box_stl), str(tmp_path / "none.txt")]) == 1
    assert "none.txt' does not exist" in capsys.readouterr().err


def test_progress_bar_and_summary_only(tmp_path, box_stl, capsys, monkeypatch):
    from cmm.metrology import mesh as mesh_mod

    monkeypatch.setattr(mesh_mod, "CHUNK", 100)
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(0, 100, 450), rng.uniform(0, 50, 450), np.full(450, 20.01)])
    path = tmp_path / "many.txt"
    path.write_text("450\n" + "\n".join(f"{x:.6f} {y:.6f} {z:.6f}" for x, y, z in pts) + "\n")  # NIST count line
    assert main(["deviation", str(box_stl), str(path), "--progress", "--summary-only"]) == 0
    cap = capsys.readouterr()
    assert "100%" in cap.err and "450/450 points" in cap.err and cap.err.count("\r") == 5
    assert "n=450" in cap.out and "max=+0.010000" in cap.out and "min=+0.010000" in cap.out
    assert len(cap.out.splitlines()) == 2  # no per-point table
