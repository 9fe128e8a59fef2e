"""`cmm fit --gdt`: geometric tolerances of the fitted feature against datum features from point files."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import trimesh

from test_gdt import box_mesh, ring

from cmm.cli import main
from cmm.metrology.transform import rotation_about_axis


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
    # an unequally disposed zone (ISO 1101 UZ): the points 0.01 out are 0.015 from a middle 0.005 inside
    inside, outside = gdt_json(capsys, ["plane", top, *datums, "--mesh", str(stl), "--gdt",
                                        "profile of a surface=0.05UZ-0.005@A|B|C", "--gdt",
                                        "profile of a surface=0.05 UZ+0.01@A|B|C"])
    assert inside["value"] == pytest.approx(0.03, abs=1e-9) and inside["offset"] == -0.005
    assert outside["value"] == pytest.approx(0.0, abs=1e-9) and "UZ" in outside["note"]
    assert main(["fit", "plane", top, *datums, "--mesh", str(stl), "--gdt",
                 "profile of a surface=0.05UZ-0.005@A|B|C"]) == 0
    assert "profile of a surface: 0.030000 (allowed 0.050000, UZ-0.005000 | A|B|C) pass" in capsys.readouterr().out
    assert main(["fit", "plane", top, *datums, "--mesh", str(stl), "--gdt", "flatness=0.05UZ+0.01"]) == 1
    assert "applies to a profile tolerance only" in capsys.readouterr().err
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


def gdt_json(capsys, argv):
    """`cmm fit ... --json`'s geometric tolerances (exit status 0)."""
    assert main(["fit", *argv, "--json"]) == 0, capsys.readouterr().err
    return json.loads(capsys.readouterr().out)["gdt"]


def test_form_tolerances_known_answers(tmp_path, capsys):
    """Circularity of three lobes of 0.005 (0.01), cylindricity of three lobes of 0.004 (0.008), straightness of
    points on two parallel lines 0.02 apart (a cylinder zone of 0.02)."""
    ring3 = write(tmp_path / "ring.txt", ring((1, 2, 3), (0, 0, 1), 10.0, [0.0], n=90, lobes=3, amp=0.005))
    (c,) = gdt_json(capsys, ["circle", ring3, "--gdt", "circularity=0.02"])
    assert c["value"] == pytest.approx(0.01, abs=1e-6) and c["ok"] and c["drf"] == ""
    cyl = write(tmp_path / "cyl.txt", ring((0, 0, 0), (0, 1, 1), 5.0, [0, 10, 20], n=60, lobes=3, amp=0.004))
    (c,) = gdt_json(capsys, ["cylinder", cyl, "--gdt", "cylindricity=0.005"])
    assert c["value"] == pytest.approx(0.008, abs=1e-5) and not c["ok"]
    zigzag = write(tmp_path / "line.txt", [(x, 0.01 if k % 2 else -0.01, 0.0)
                                           for k, x in enumerate(np.linspace(0, 40, 41))])
    (s,) = gdt_json(capsys, ["line", zigzag, "--gdt", "straightness=0.01"])
    assert s["value"] == pytest.approx(0.02, abs=1e-6) and not s["ok"]


def test_orientation_known_answers(tmp_path, capsys, datums):
    """A bore leaning 0.1 deg from A's normal over 20 mm: perpendicularity 20 sin(0.1 deg); a face 0.1 deg off
    its basic 30 deg to A (turned about A): angularity 30 sin(0.1 deg)."""
    t = math.radians(0.1)
    u = np.array([math.sin(t), 0, math.cos(t)])
    bore_pts = write(tmp_path / "bore.txt", ring((5, 5, 0), u, 4.0, [0.0, 20.0]))
    (p,) = gdt_json(capsys, ["cylinder", bore_pts, *datums, "--gdt", "perpendicularity=0.05@A"])
    assert p["value"] == pytest.approx(20 * math.sin(t), rel=1e-6) and p["ok"] and p["drf"] == "A"
    a = math.radians(30.1)
    e1 = np.array([math.cos(a), 0, -math.sin(a)])
    s = np.array([(x, y) for x in np.linspace(0, 30, 7) for y in np.linspace(0, 30, 7)])
    face = (s[:, :1] * e1 + s[:, 1:] * np.array([0, 1.0, 0])) @ rotation_about_axis((0, 0, 1), 0.7).T + (3, 4, 40)
    (g,) = gdt_json(capsys, ["plane", write(tmp_path / "face.txt", face), *datums, "--gdt", "angularity=0.1@A",
                             "--angle", "30"])
    assert g["value"] == pytest.approx(30 * math.sin(math.radians(0.1)), rel=1e-6) and g["ok"]


def test_concentricity_and_runout_known_answers(tmp_path, capsys):
    """Against datum A, the axis of a bore on z: a circle 0.004 off it (concentricity 0.008); a diameter 0.02
    off it, 0.005 larger in radius further up (circular runout 0.04, total 0.045)."""
    a = ["--datum", "A=cylinder:" + write(tmp_path / "a.txt", ring((0, 0, 0), (0, 0, 1), 5.0, [-20.0, -5.0]))]
    circle = write(tmp_path / "c.txt", ring((0, 0.004, 12), (0, 0, 1), 8.0, [0.0]))
    (c,) = gdt_json(capsys, ["circle", circle, *a, "--gdt", "concentricity=0.01@A"])
    assert c["value"] == pytest.approx(0.008, abs=1e-9) and c["ok"]
    e = 0.02
    sections = np.r_[ring((e, 0, 0), (0, 0, 1), 10.0, [10.0], n=360), ring((e, 0, 0), (0, 0, 1), 10.005, [20.0], n=360)]
    shaft = write(tmp_path / "shaft.txt", sections)
    circ, total = gdt_json(capsys, ["cylinder", shaft, *a, "--gdt", "circular runout=0.05@A",
                                    "--gdt", "total runout=0.05@A"])
    assert circ["value"] == pytest.approx(2 * e, abs=1e-9) and circ["ok"]
    assert total["value"] == pytest.approx(2 * e + 0.005, abs=1e-9) and total["drf"] == "A"


def test_profile_of_a_line_known_answer(tmp_path, capsys, datums):
    """A section y = 10 across the top and the right face of a 40 x 30 x 20 block whose right face is 0.015 out:
    located by A|B|C the profile is 0.03; without datums the section best-fits in its plane (0)."""
    stl = tmp_path / "block.stl"
    box_mesh().export(stl)
    top = np.c_[np.linspace(2, 38, 10), np.full(10, 10.0), np.full(10, 20.0)]
    side = np.c_[np.full(6, 40.015), np.full(6, 10.0), np.linspace(2, 18, 6)]
    section = write(tmp_path / "section.txt", np.r_[top, side])
    located, free = gdt_json(capsys, ["plane", section, *datums, "--mesh", str(stl),
                                      "--gdt", "profile of a line=0.02@A|B|C", "--gdt", "profile of a line=0.02"])
    assert located["value"] == pytest.approx(0.03, abs=1e-9) and not located["ok"] and located["drf"] == "A|B|C"
    assert free["value"] == pytest.approx(0.0, abs=1e-6)


def test_datum_shift_at_mmb_and_datum_targets(tmp_path, capsys, datums):
    """B, a bore of 20.04 referenced at MMB 20.00, lets the frame shift 0.02 across it: a hole 0.05 off its
    nominal radially is at 0.06, 0.1 RFS. Datum A from three target points of its face ignores a high spot
    elsewhere on it: a top face parallel to those targets is parallel 0, against A from the whole face it is not."""
    a = datums[:2]
    b = ["--datum", "B=cylinder:" + write(tmp_path / "b.txt", ring((0, 0, 0), (0, 0, 1), 10.02, [2.0, 8.0]))]
    hole = write(tmp_path / "hole.txt", ring((30.05, 0, 5), (0, 0, 1), 3.0, [0.0]))
    rfs, mmb = gdt_json(capsys, ["circle", hole, *a, *b, "--datum-size", "B=20.0,20.1,hole", "--nominal", "30,0,5,0,0,1",
                                 "--gdt", "position=0.1@A|B", "--gdt", "position=0.1@A|B(M)"])
    assert rfs["value"] == pytest.approx(0.1, abs=1e-9) and rfs["drf"] == "A|B"
    assert mmb["value"] == pytest.approx(0.06, abs=1e-9) and "datum shift" in mmb["note"] and mmb["drf"] == "A|B(M)"
    face = grid_plane((1, 1, 0), (0, 1, 0), (1, 0, 0))
    face[6] = face[6] + (0, 0, 0.05)  # a high spot, not a target
    a_file = write(tmp_path / "a_spot.txt", face)
    top = write(tmp_path / "top.txt", grid_plane((1, 1, 30), (0, 1, 0), (1, 0, 0)))
    (targets,) = gdt_json(capsys, ["plane", top, "--datum", f"A=plane:{a_file}", "--datum-targets", "A=1,5,21",
                                   "--gdt", "parallelism=0.01@A"])
    assert targets["value"] == pytest.approx(0.0, abs=1e-9)
    (whole,) = gdt_json(capsys, ["plane", top, "--datum", f"A=plane:{a_file}", "--gdt", "parallelism=0.01@A"])
    assert whole["value"] > 1e-3
    assert main(["fit", "plane", top, "--datum", f"A=plane:{a_file}", "--datum-targets", "A=1,5,26",
                 "--gdt", "parallelism=0.01@A"]) == 1
    assert "--datum-targets A: the targets are point numbers of" in capsys.readouterr().err
    assert main(["fit", "plane", top, "--datum-targets", "D=1,2,3", "--gdt", "flatness=0.01"]) == 1
    assert "datum D has a size or targets but no --datum D=KIND:FILE" in capsys.readouterr().err
