"""`cmm fit --gdt`: geometric tolerances of the fitted feature against datum features from point files."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import trimesh

from cmm.cli import main


def write(path, points):
    path.write_text("\n".join(" ".join(repr(float(v)) for v in p) for p in points) + "\n")
    return str(path)


def grid_plane(origin, e1, e2, n=5, size=20.0):
    o, e1, e2 = (np.asarray(v, float) for v in (origin, e1, e2))
    return [o + a * e1 + b * e2 for a in np.linspace(0, size, n) for b in np.linspace(0, size, n)]


def bore(center, radius, heights, n=12):
    return [np.asarray(center, float) + (radius * math.cos(t), radius * math.sin(t), z)
            for z in heights for t in np.linspace(0, 2 * math.pi, n, endpoint=False)]


@pytest.fixture
def datums(tmp_path):
    # A: bottom z = 0 (normal -z), B: left x = 0 (normal -x), C: front y = 0 (normal -y) of a block
    return ["--datum", "A=plane:" + write(tmp_path / "a.txt", grid_plane((1, 1, 0), (0, 1, 0), (1, 0, 0))),
            "--datum", "B=plane:" + write(tmp_path / "b.txt", grid_plane((0, 1, 1), (0, 0, 1), (0, 1, 0))),
            "--datum", "C=plane:" + write(tmp_path / "c.txt", grid_plane((1, 0, 1), (1, 0, 0), (0, 0, 1)))]


def test_position_with_mmc_bonus_from_the_command_line(tmp_path, capsys, datums):
    hole = write(tmp_path / "hole.txt", bore((30.03, 40.04, 0), 5.03, [2.0, 8.0]))
    assert main(["fit", "cylinder", hole, *datums, "--gdt", "position=0.05@A|B|C", "--nominal", "30,40,0,0,0,1",
                 "--json"]) == 0
    (rfs,) = json.loads(capsys.readouterr().out)["gdt"]
    # the frame: Z along A's normal turned into the part (+z), X along B's (+x): the hole is 0.05 off (30, 40)
    assert rfs["drf"] == "A|B|C" and rfs["value"] == pytest.approx(0.1, abs=1e-9) and not rfs["ok"]
    assert main(["fit", "cylinder", hole, *datums, "--gdt", "position=0.05@A|B|C", "--nominal", "30,40,0,0,0,1",
                 "--material", "MMC", "--size-limits", "10.0,10.1", "--internal", "--json"]) == 0
    (mmc,) = json.loads(capsys.readouterr().out)["gdt"]
    assert mmc["value"] == pytest.approx(0.1, abs=1e-9) and mmc["bonus"] == pytest.approx(0.06, abs=1e-9)
    assert mmc["ok"] and mmc["material"] == "MMC"
    assert main(["fit", "cylinder", hole, *datums, "--gdt", "position=0.05@A|B|C", "--nominal", "30,40,0,0,0,1"]) == 0
    out = capsys.readouterr().out
    assert "position: 0.100000 (allowed 0.050000 | A|B|C) FAIL" in out


def test_form_and_orientation(tmp_path, capsys, datums):
    t = math.radians(0.1)
    top = write(tmp_path / "top.txt", [(x, y, 30 + x * math.tan(t)) for x in np.linspace(0, 40, 5)
                                       for y in np.linspace(0, 30, 5)])
    assert main(["fit", "plane", top, *datums, "--gdt", "flatness=0.01", "--gdt", "parallelism=0.05@A",
                 "--json"]) == 0
    flat, par = json.loads(capsys.readouterr().out)["gdt"]
    assert flat["value"] == pytest.approx(0.0, abs=1e-9) and flat["drf"] == ""
    assert par["value"] == pytest.approx(40 * math.tan(t), rel=1e-9) and not par["ok"]


def test_profile_needs_a_mesh_and_datums_must_constrain(tmp_path, capsys, datums):
    top = write(tmp_path / "top.txt", [(x, y, 20.01) for x in np.linspace(2, 38, 4) for y in np.linspace(2, 28, 4)])
    assert main(["fit", "plane", top, "--gdt", "profile of a surface=0.05"]) == 1
    assert "profile tolerance needs the part mesh" in capsys.readouterr().err
    stl = tmp_path / "block.stl"
    trimesh.creation.box(extents=(40, 30, 20), transform=np.diag([1, 1, 1, 1.0]) + np.c_[
        np.zeros((4, 3)), [20, 15, 10, 0]]).export(stl)
    assert main(["fit", "plane", top, *datums, "--gdt", "profile of a surface=0.05@A|B|C", "--mesh", str(stl),
                 "--json"]) == 0
    (prof,) = json.loads(capsys.readouterr().out)["gdt"]
    assert prof["value"] == pytest.approx(0.02, abs=1e-9)
    assert main(["fit", "plane", top, "--datum", "A=plane:" + str(tmp_path / "a.txt"),
                 "--datum", "D=plane:" + str(tmp_path / "top.txt"), "--gdt", "position=0.05@A|D",
                 "--nominal", "0,0,0"]) == 1
    assert "datum D (plane) is parallel to datum A" in capsys.readouterr().err
    assert main(["fit", "plane", top, "--gdt", "parallelism=0.05@A"]) == 1
    assert "datum A is not given" in capsys.readouterr().err


def test_coaxiality_to_a_common_datum_axis(tmp_path, capsys):
    """Bores A (z 0..10) and B (z 50..60, 0.02 off in x) form the common axis A-B through their centres; a bore at
    z 20..30 on that line but 0.03 off in y has coaxiality 0.06 to A-B (its axis parallel to A-B's)."""
    a = write(tmp_path / "a.txt", bore((0, 0, 0), 5.0, [1.0, 9.0]))
    b = write(tmp_path / "b.txt", bore((0.02, 0, 50), 5.0, [1.0, 9.0]))
    tilt = 0.02 / 50
    mid = write(tmp_path / "mid.txt", [p + (tilt * (p[2] - 25.0), 0, 0) for p in bore((0.008, 0.03, 20), 5.0, [1.0, 9.0])])
    assert main(["fit", "cylinder", mid, "--datum", f"A=cylinder:{a}", "--datum", f"B=cylinder:{b}",
                 "--gdt", "coaxiality=0.05@A-B", "--json"]) == 0
    (r,) = json.loads(capsys.readouterr().out)["gdt"]
    assert r["value"] == pytest.approx(0.06, abs=1e-6) and r["drf"] == "A-B" and not r["ok"]
    assert main(["fit", "cylinder", mid, "--datum", f"A=cylinder:{a}", "--datum", f"B=plane:{a}",
                 "--gdt", "coaxiality=0.05@A-B"]) != 0
    assert "common datum A-B: A is an axis and B a plane" in capsys.readouterr().err
