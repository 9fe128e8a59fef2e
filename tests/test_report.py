"""The inspection report: header, every feature with tolerances and verdicts, colour map, form plots, CSV."""

from __future__ import annotations

import csv
import html
import io
import json
import re

import pytest

import session_support as sup
from cmm.metrology.colour_scale import ColourScale
from cmm.program import toml_program as prog
from cmm.session.export import resolve_part_mesh
from cmm.journal.session import Session
from cmm.session.report import NO_ALIGNMENT, features_csv, render
from cmm.journal.store import DirectoryStore, load_session


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    root = tmp_path_factory.mktemp("report")
    sup.recorded_copy(root)
    return load_session(DirectoryStore(root), "taught")


def _with(session: Session, *extra: dict, drop=lambda e: False) -> Session:
    """The session with extra events appended (and some removed): a variant to report on."""
    events = [e for e in session.events if not drop(e)]
    seq = max(e["seq"] for e in events)
    events += [{"seq": seq + k + 1, "time": events[-1]["time"] + k + 1, **e} for k, e in enumerate(extra)]
    return Session.from_events(events, session.name)


def test_the_report_contains_every_feature_with_its_verdict(session):
    mesh = resolve_part_mesh(session)
    assert mesh is not None
    page = render(session, mesh=mesh)
    assert page.startswith("<!DOCTYPE html>") and "<script" not in page
    assert "@media print" in page and "@page" in page
    for f in session.features.values():
        assert f"<b>{f.name}</b>" in page
    # deviation plot, top, front and isometric colour map views, one form plot per feature
    assert page.count("<svg") == 4 + len(session.features)
    assert page.count("aria-label=\"form plot ") == len(session.features)
    assert len(re.findall(r"<title>hit \d+:", page)) >= len(session.hits)
    assert "class='verdict PASS'>PASS<" in page
    # true position is a diameter against a cylindrical zone (ISO 1101), sizes are +- tolerances
    assert "position ⌀" in page and "<td>0.0400</td>" in page and "cylindricity" in page and "sphericity" in page
    # the legend of the shared colour scale, as the 3D scene shows it
    for _colour, label in ColourScale(0.02).legend():
        assert html.escape(label) in page
    # nothing printed raw: no Python dicts, no 15-digit floats
    assert "{'" not in page and not re.search(r"\d\.\d{9,}", page)
    assert "tip radius</dt><dd>1.0000 mm" in page
    assert NO_ALIGNMENT not in page  # this session was aligned (best fit)


def test_header_fields_calibration_and_worded_machine_events(session):
    variant = _with(session, {"kind": "info", "part_number": "BR-7", "drawing": "DWG-1234 rev C",
                              "operator": "A. Operator", "temperature": 20.4},
                    {"kind": "error", "source": "machine:deadman", "message": "{'after': 0.16}"},
                    {"kind": "error", "source": "machine:deadman", "message": "{'after': 0.17}"},
                    {"kind": "error", "source": "machine:contact", "message": "{'position': [201.5, 150.25, 38.0]}"})
    start = variant.events[0]
    start["calibration"] = {"probe": {"date": "2026-11-20T10:00:00+00:00", "tip_radius": 0.9961}, "machine": None,
                            "problems": []}
    page = render(variant)
    for text in ("BR-7", "DWG-1234 rev C", "A. Operator", "20.4 °C", "probe qualified 2026-11-20",
                 "geometry not calibrated"):
        assert text in page, text
    assert "The jog stopped: the browser stopped refreshing it (dead-man). <span class='muted'>(&times;2)" in page
    assert "Unexpected probe contact at X 201.500 Y 150.250 Z 38.000" in page
    assert "{'" not in page


def test_no_alignment_is_said_and_a_missing_nominal_is_never_a_pass(session):
    def unaligned(e):
        return e["kind"] == "alignment"

    def strip_nominal(e):
        if e["kind"] == "feature" and e["name"] == "boss":
            e = dict(e, nominal=None)
        return e

    events = [strip_nominal(e) for e in session.events if not unaligned(e)]
    variant = Session.from_events(events, session.name)
    page = render(variant)
    assert NO_ALIGNMENT in page
    assert "class='verdict INCOMPLETE'" in page and "without a nominal" in page
    boss_rows = [r for r in features_csv(variant).splitlines() if r.startswith("boss,")]
    assert len(boss_rows) == 3
    diameter, position, form = (next(csv.reader([r])) for r in boss_rows)
    assert diameter[6] == "" and diameter[12] == "no nominal"  # blank nominal: not a pass
    assert position[4] == "position ⌀" and position[9] == "" and position[12] == "no nominal"
    assert form[4] == "cylindricity" and form[12] == "pass"


def test_tolerances_from_a_program_decide_pass_and_fail(session):
    program = prog.teach(session)
    program.feature("dome").tolerance["size"] = 0.001  # the 5-point cap is ~16 um small
    page = render(session, mesh=resolve_part_mesh(session), program=program)
    assert "FAIL (1 characteristic out of tolerance)" in page
    assert "class='fail" in page and "<td class='ng'>FAIL</td>" in page
    rows = list(csv.DictReader(io.StringIO(features_csv(session, program=program))))
    dome = next(r for r in rows if r["feature"] == "dome" and r["characteristic"] == "diameter")
    assert dome["result"] == "FAIL" and float(dome["upper_tol"]) == 0.001
    assert float(dome["out_of_tolerance"]) == pytest.approx(abs(float(dome["deviation"])) - 0.001, abs=1e-6)
    nominal = next(e["nominal"] for e in session.events if e.get("name") == "dome" and e["kind"] == "feature")
    assert float(dome["nominal"]) == pytest.approx(2 * nominal["radius"], abs=1e-6)
    json.dumps(rows)


def test_the_report_renders_without_the_part_mesh(session):
    page = render(session)
    assert "hits only" in page and "No deviations" in page


def test_a_criterion_fits_proof_domain_is_stated_in_the_report(session):
    """A cylinder by a criterion carries its proof record; the report names the domain it was proven in."""
    proof = {"proven": True, "cone_deg": 10.0, "gap_um": 0.0, "cells": 644, "near_cells": 520}

    def with_proof(e):
        return dict(e, method="mcc", proof=proof) if e.get("kind") == "feature" and e.get("name") == "boss" else e

    variant = Session.from_events([with_proof(e) for e in session.events], session.name)
    page = render(variant)
    assert "global optimum proven among axes within 10 deg of the LS axis (644 direction cells bounded)" in page
    assert "proven among" not in render(session)  # least-squares features state nothing of the kind
