"""The HTML inspection report: every feature, tolerances, deviation plot and part views, printable."""

from __future__ import annotations

import re

import pytest

import session_support as sup
from cmm.session import program as prog
from cmm.session.export import resolve_part_mesh
from cmm.session.report import render
from cmm.session.store import DirectoryStore, load_session


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    root = tmp_path_factory.mktemp("report")
    sup.recorded_copy(root)
    return load_session(DirectoryStore(root), "taught")


def test_the_report_contains_every_feature_with_its_verdict(session):
    mesh = resolve_part_mesh(session)
    assert mesh is not None
    page = render(session, mesh=mesh)
    assert page.startswith("<!DOCTYPE html>") and "<script" not in page
    assert "@media print" in page and "@page" in page
    for f in session.features.values():
        assert f">{f.name}</td>" in page
    assert page.count("<svg") == 3  # deviation plot, top and front views
    assert len(re.findall(r"<title>hit \d+:", page)) == len(session.hits)
    assert "result: <b>PASS</b>" in page
    assert "diameter" in page and "&plusmn; 0.0200" in page


def test_tolerances_from_a_program_decide_pass_and_fail(session):
    program = prog.teach(session)
    program.feature("dome").tolerance["size"] = 0.001  # the 5-point cap is ~16 um small
    page = render(session, mesh=resolve_part_mesh(session), program=program)
    assert "FAIL (1 characteristic out of tolerance)" in page
    assert "class='fail'" in page and "&plusmn; 0.0010" in page


def test_the_report_renders_without_the_part_mesh(session):
    page = render(session)
    assert "hits only" in page and "No deviations" in page
