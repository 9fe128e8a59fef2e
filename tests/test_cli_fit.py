"""`cmm fit`: JSON output, table output, input parsing and error exit codes."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import knownanswer as ka
from cmm.cli import main

TOL = 1e-9


def write(path, points, header="x, y, z", sep=", "):
    lines = ["# probed by the test", header] if header else []
    lines += [sep.join(repr(float(v)) for v in p) for p in points]
    lines.insert(3, "")  # a blank line inside the data
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def run_json(capsys, *argv):
    assert main(["fit", *argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_sphere_json_full_precision(tmp_path, capsys):
    data = ka.sphere(np.array([1000.0, 20.0, -30.0]), 12.5)
    out = run_json(capsys, "sphere", write(tmp_path / "s.txt", data.points))
    assert out["kind"] == "sphere" and out["method"] == "ls" and out["n_points"] == len(data.points)
    assert np.abs(np.array(out["center"]) - data.answer["center"]).max() < TOL
    assert abs(out["radius"] - 12.5) < TOL
    assert out["form"] == pytest.approx(np.ptp(data.residuals), abs=TOL)
    assert out["sigma"] > 0


def test_cylinder_and_cone_keys(tmp_path, capsys):
    cyl = ka.cylinder(np.array([10.0, 0, 0]), [0, 0.6, 0.8], 5.0)
    out = run_json(capsys, "cylinder", write(tmp_path / "c.txt", cyl.points, sep=" "))
    assert {"point", "direction", "radius", "form", "sigma"} <= out.keys()
    p, u = np.array(out["point"]), np.array(out["direction"])
    c = cyl.points.mean(axis=0)
    assert abs((c - p) @ u) < 1e-9  # the location point is the foot of the data centroid on the axis
    rel = p - [10.0, 0, 0]
    assert np.linalg.norm(rel - (rel @ u) * u) < TOL  # ... and lies on the axis
    cone = ka.cone(np.array([0.0, 0, 5]), [0, 0, 1.0], np.radians(15.0))
    out = run_json(capsys, "cone", write(tmp_path / "k.txt", cone.points))
    assert np.abs(np.array(out["apex"]) - [0, 0, 5]).max() < TOL
    assert out["half_angle_deg"] == pytest.approx(15.0, abs=1e-7)
    assert np.allclose(out["direction"], [0, 0, 1], atol=TOL)


@pytest.mark.parametrize("kind, keys", [("line", {"point", "direction"}), ("plane", {"point", "normal"}),
                                        ("circle", {"center", "normal", "radius"})])
def test_other_kinds(tmp_path, capsys, kind, keys):
    pts = ka.circle3d(np.zeros(3), [0, 0, 1.0], 10.0).points if kind != "line" else ka.line(np.zeros(3), [1, 1, 0.0]).points
    out = run_json(capsys, kind, write(tmp_path / "p.txt", pts))
    assert keys <= out.keys() and out["kind"] == kind


def test_method_minzone_and_table(tmp_path, capsys):
    path = write(tmp_path / "c.txt", ka.circle3d(np.zeros(3), [0, 0, 1.0], 10.0, form=0.01).points, header=None)
    out = run_json(capsys, "circle", path, "--method", "minzone")
    assert out["method"] == "minzone" and out["form"] <= 0.01 + 1e-12
    assert main(["fit", "circle", path, "--method", "mcc"]) == 0
    table = capsys.readouterr().out
    assert "radius" in table and "mcc" in table


def test_unsupported_method_exit_1(tmp_path, capsys):
    path = write(tmp_path / "p.txt", ka.plane(np.zeros(3), [0, 0, 1.0]).points)
    assert main(["fit", "plane", path, "--method", "mic"]) == 1
    err = capsys.readouterr().err
    assert "not available for a plane" in err


def test_too_few_points_exit_1(tmp_path, capsys):
    path = write(tmp_path / "p.txt", [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    assert main(["fit", "sphere", path]) == 1
    assert "a sphere needs at least 4 points, got 3" in capsys.readouterr().err


def test_missing_file_exit_2(tmp_path, capsys):
    assert main(["fit", "plane", str(tmp_path / "nope.txt")]) == 2
    assert "nope.txt' does not exist" in capsys.readouterr().err


def test_malformed_row_names_the_line(tmp_path, capsys):
    path = tmp_path / "bad.txt"
    path.write_text("x y z\n1 2 3\n4 5 6\n7 eight 9\n")
    assert main(["fit", "plane", str(path)]) == 2
    assert "line 4" in capsys.readouterr().err
    path.write_text("1 2 3\n4 5\n")
    assert main(["fit", "plane", str(path)]) == 2
    assert "line 2" in capsys.readouterr().err


def test_module_entry_point(tmp_path):
    path = write(tmp_path / "p.txt", ka.plane(np.zeros(3), [0, 0, 1.0]).points)
    proc = subprocess.run([sys.executable, "-m", "cmm.cli", "fit", "plane", path, "--json"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["kind"] == "plane"


def test_nist_point_count_first_line(tmp_path, capsys):
    """NIST data set format: the first line is the number of points."""
    data = ka.circle3d_standard(np.array([1000.0, -700.0, 650.0]), np.array([0.3, -0.5, 0.81]), 20.0, m=40)
    path = tmp_path / "c.ds"
    path.write_text(f"{len(data.points)}\n" + "\n".join(" ".join(repr(float(v)) for v in p) for p in data.points) + "\n")
    out = run_json(capsys, "circle", str(path))
    assert out["n_points"] == 40
    assert np.abs(np.array(out["center"]) - data.answer["center"]).max() < TOL
    assert abs(out["radius"] - 20.0) < TOL
    # uncertainties and warnings are in the JSON
    assert set(out["uncertainty"]) == {"center", "normal", "radius", "diameter"}
    assert all(v > 0 for v in out["uncertainty"].values()) and out["warnings"] == []
    path.write_text("41\n" + "\n".join(" ".join(repr(float(v)) for v in p) for p in data.points) + "\n")
    assert main(["fit", "circle", str(path)]) == 2
    assert "says 41 points but holds 40" in capsys.readouterr().err


def test_warning_in_table_and_json(tmp_path, capsys):
    rng = np.random.default_rng(3)
    t = np.radians(5.0) * rng.random(30)
    pts = np.column_stack([50 * np.cos(t), 50 * np.sin(t), rng.uniform(0, 20, 30)]) + 0.001 * rng.standard_normal((30, 3))
    path = write(tmp_path / "arc.txt", pts)
    out = run_json(capsys, "cylinder", path)
    assert any("poorly" in w for w in out["warnings"]) and out["uncertainty"]["radius"] > 0.01
    assert main(["fit", "cylinder", path]) == 0
    text = capsys.readouterr().out
    assert "uncertainty" in text and "! the points determine the cylinder" in text


def test_fast_reader_agrees_with_the_line_parser_and_keeps_line_errors(tmp_path):
    from cmm.metrology.pointfile import PointFileError, parse_points, read_points_array

    pts = np.random.default_rng(1).uniform(-1000, 1000, (500, 3))
    text = "\n".join(f"{float(x)!r}, {float(y)!r}; {float(z)!r}" for x, y, z in pts) + "\n"
    path = tmp_path / "plain.txt"
    path.write_text(text)
    fast = read_points_array(str(path))
    assert np.array_equal(fast, np.array(parse_points(text.splitlines())))
    assert np.array_equal(fast, pts)
    path.write_text("1 2 3 4\n5 6\n")  # right number of values, wrong rows
    with pytest.raises(PointFileError, match="line 1"):
        read_points_array(str(path))


def test_a_cylinder_criterion_reports_its_proof_domain(tmp_path, capsys):
    """`cmm fit cylinder --method mcc`: the JSON carries the proof record, the table states it in words."""
    data = ka.cylinder(np.array([100.0, 20.0, -30.0]), [0.0, 0.3, 1.0], 20.0, m=200, length=40.0, form=0.01)
    path = write(tmp_path / "c.txt", data.points)
    out = run_json(capsys, "cylinder", path, "--method", "mcc")
    assert out["proof"]["proven"] and out["proof"]["cone_deg"] == pytest.approx(10.0) and out["warnings"] == []
    assert out["proof"]["cells"] >= out["proof"]["near_cells"] > 0
    assert main(["fit", "cylinder", path, "--method", "mcc"]) == 0
    assert "global optimum proven among axes within 10 deg of the LS axis" in capsys.readouterr().out
