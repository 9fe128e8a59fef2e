"""QIF 3 Results (cmm.session.qif): every document the tests write validates against the QIF 3.0.0 schemas in
../shared/qif (lxml, offline; skipped with the reason when they are absent), and its values are the report's and
the DMIS output's, characteristic by characteristic.

- a recorded session with every feature kind and every geometric tolerance (tests/test_report_numbers.py's
  fixture): the QIF characteristics are the report CSV's rows, in order, with the same nominal, limits, actual
  and verdict; the features, datums, part (CAD) and expanded uncertainties are there;
- ``cmm run PROGRAM --qif``: a DMIS run of the sample part; its FA sizes and TA values are the QIF's;
- ``cmm sessions export --qif`` of that run and of a re-evaluated session.
"""

from __future__ import annotations

import math
import re
import uuid
from pathlib import Path

import pytest
import qif_support
from qif_support import NS
from test_report_numbers import measured  # noqa: F401 - the module-scoped recorded session with every kind

from cmm.session.qif import write_qif
from cmm.session.qif_map import expanded_uncertainty
from cmm.session.report import features_csv

SAMPLE = Path(__file__).resolve().parents[1] / "cmm" / "data" / "sample_part.dmi"
STATUS = {"pass": "PASS", "FAIL": "FAIL", "check": "INDETERMINATE", "no nominal": "NOT_ANALYZED"}


def _f(e, path):
    x = e.find(path, NS)
    return None if x is None else float(x.text)


def characteristics(root) -> list[dict]:
    """Per characteristic item, in document order: its name, type, definition, nominal and measurement values."""
    by_id = {e.get("id"): e for e in root.iter() if e.get("id") is not None}
    out = []
    for item in root.find("q:Characteristics/q:CharacteristicItems", NS):
        nominal = by_id[item.find("q:CharacteristicNominalId", NS).text]
        definition = by_id[nominal.find("q:CharacteristicDefinitionId", NS).text]
        meas = next(m for m in root.find(".//q:CharacteristicMeasurements", NS)
                    if m.find("q:CharacteristicItemId", NS).text == item.get("id"))
        value = meas.find("q:Value", NS)
        attrs = {a.get("name"): a.get("value") for a in meas.findall("q:Attributes/*", NS)}
        out.append({"name": item.find("q:Name", NS).text, "type": item.tag.split("}")[1][:-len("CharacteristicItem")],
                    "target": _f(nominal, "q:TargetValue"), "max": _f(definition, "q:Tolerance/q:MaxValue"),
                    "min": _f(definition, "q:Tolerance/q:MinValue"), "zone": _f(definition, "q:ToleranceValue"),
                    "drf": definition.find("q:DatumReferenceFrameId", NS),
                    "value": None if value is None else float(value.text),
                    "combined": None if value is None or value.get("combinedUncertainty") is None
                    else float(value.get("combinedUncertainty")),
                    "U": None if "ExpandedUncertainty" not in attrs else float(attrs["ExpandedUncertainty"]),
                    "status": meas.find("q:Status/q:CharacteristicStatusEnum", NS).text,
                    "features": [by_id[i.text].find("q:FeatureName", NS).text
                                 for i in item.findall("q:FeatureItemIds/q:Id", NS)]})
    return out


DMIS_ONLY = re.compile(r" [A-Z]+ T\(\w+\)$")  # a DMIS run's tolerances the report has no row for


def check_against_csv(root, csv_text: str) -> list[dict]:
    """Every report CSV row is the QIF characteristic at the same place: nominal, limits, actual, verdict."""
    chars = [c for c in characteristics(root) if not DMIS_ONLY.search(c["name"])]
    rows = [r.split(",") for r in csv_text.splitlines()[1:]]
    assert len(chars) == len(rows) and rows
    for c, r in zip(chars, rows):
        feature, kind, _method, _hits, name, _unit, nominal, upper, lower, actual, _dev, _oot, result = r[:13]
        assert c["name"] == " ".join(f"{feature} {name}".split()), (c["name"], r)
        assert c["status"] == STATUS[result], (c["name"], result)
        if actual:
            assert f"{c['value']:.6f}" == actual, c["name"]
        else:
            assert c["value"] is None, c["name"]
        if c["max"] is not None:  # limits around a target: sizes, distances, angles, locations
            assert f"{c['max']:.6f}" == upper and f"{c['min']:.6f}" == lower, c["name"]
            assert (f"{c['target']:.6f}" if c["target"] is not None else "") == nominal, c["name"]
        else:  # a zone: form, orientation, position, runout, profile (the allowed one, bonus included in the CSV)
            assert c["zone"] is not None and c["zone"] <= float(upper) + 1e-12 and float(lower) == 0.0, c["name"]
            if kind != "gdt":
                assert f"{c['zone']:.6f}" == upper, c["name"]
    return chars


def test_every_feature_kind_and_gdt_characteristic_in_qif_is_the_reports(measured, tmp_path):  # noqa: F811
    s, mesh = measured.session, measured.mesh
    path = write_qif(s, tmp_path / "numbers.qif", mesh=mesh, operator="A. Operator", station="bench 3",
                     program_name="numbers.toml", report="numbers-report.html")
    root = qif_support.validate(path)
    chars = check_against_csv(root, features_csv(s, mesh=mesh))
    assert {c["type"] for c in chars} >= {"Diameter", "SphericalDiameter", "Angle", "Position", "Flatness",
                                          "Straightness", "Circularity", "Cylindricity", "Conicity", "Parallelism",
                                          "Perpendicularity", "Angularity", "Concentricity", "Coaxiality",
                                          "CircularRunout", "TotalRunout", "SurfaceProfile", "LineProfile",
                                          "DistanceBetween", "UserDefinedLinear"}
    # geometric tolerances with datums refer to a datum reference frame; the datums name their features
    assert all(c["drf"] is not None for c in chars if c["type"] in ("Parallelism", "Perpendicularity", "TotalRunout"))
    labels = {d.find("q:DatumLabel", NS).text for d in root.findall(".//q:DatumDefinition", NS)}
    assert labels == set("ABCDEFG")
    assert root.findall(".//q:CompoundDatum", NS)  # the common datum E-F
    assert all(d.find("q:FeatureNominalIds/q:Id", NS) is not None for d in root.findall(".//q:DatumDefinition", NS))
    # the features: every fitted one with its actuals (the diameter to the last digit of the fit)
    st = s.state
    items = {e.find("q:FeatureName", NS).text: e for e in root.find("q:Features/q:FeatureItems", NS)}
    assert set(items) == {f.name for f in st.features.values()}
    meas = {m.find("q:FeatureItemId", NS).text: m for m in root.find(".//q:MeasuredFeatures", NS)}
    for f in st.features.values():
        m = meas[items[f.name].get("id")]
        if "diameter" in f.fit and f.kind != "cone":
            assert float(m.find("q:Diameter", NS).text) == f.fit["diameter"], f.name
    # the part from CAD: its model, and the nominals that came from it
    part = root.find(".//q:Part", NS)
    assert part.find(".//q:DigitalModel/q:Name", NS).text == "sample part"
    assert len(part.findall("q:FeatureNominalIds/q:Id", NS)) == sum(1 for f in st.features.values() if f.nominal)
    # station, program, operator, QPIds, the report
    assert root.find(".//q:MeasurementDevice/q:Name", NS).text == "bench 3"
    assert root.find(".//q:InspectionProgram/q:File/q:Name", NS).text == "numbers.toml"
    assert root.find(".//q:InspectionOperator/q:Name", NS).text == "A. Operator"
    assert uuid.UUID(root.find("q:QPId", NS).text) and uuid.UUID(root.find(".//q:ThisResultsInstanceQPId", NS).text)
    assert root.find(".//q:ExternalFileReference/q:URI", NS).text == "numbers-report.html"
    # expanded uncertainty: the characteristic's U from the feature's budget where it has one (the report's and the
    # CSV's value), else U = 2 u of the fit (the scatter-based value), on every size and position with one
    diam = [(f, c) for f in st.features.values() for c in f.characteristics() if c.name == "diameter"]
    assert diam
    by_name = {c["name"]: c for c in chars}
    for f, c in diam:
        q = by_name[f"{f.name} diameter"]
        want = c.uncertainty if c.uncertainty is not None else 2.0 * f.fit["uncertainty"]["diameter"]
        assert q["U"] == pytest.approx(want, rel=1e-12, abs=1e-15), f.name
        k = c.uncertainty_k if c.uncertainty is not None else 2.0  # the budget's k (Student's t for few dof)
        assert q["combined"] == pytest.approx(q["U"] / k, rel=1e-9, abs=1e-15)
    assert any(c["U"] for c in chars if c["type"] == "Position")
    # every characteristic that carries its own U (the feature's budget: sizes, locations, form too) has it in QIF
    own = [(f"{f.name} {c.name}", c.uncertainty) for f in st.features.values() for c in f.characteristics()
           if c.uncertainty is not None]
    assert any(name.endswith(("flatness", "roundness", "cylindricity", "sphericity")) for name, _ in own)
    for name, u in own:
        assert by_name[" ".join(name.split())]["U"] == pytest.approx(u, rel=1e-12, abs=1e-15), name
    # the same session exported twice: the same QPId (a re-export replaces, it does not add a part)
    again = qif_support.validate(write_qif(s, tmp_path / "again.qif", mesh=mesh))
    assert again.find("q:QPId", NS).text == root.find("q:QPId", NS).text


def test_a_characteristics_own_expanded_uncertainty_wins_over_the_scatter():
    """The hook for an uncertainty budget: a characteristic that carries its U is written with it."""
    from dataclasses import dataclass

    from cmm.metrology.characteristics import Characteristic

    @dataclass(frozen=True)
    class WithU(Characteristic):
        expanded_uncertainty: float = 0.0

    fit = {"uncertainty": {"diameter": 0.0005}}
    plain = Characteristic("bore", "diameter", 30.0, 30.01, 0.02, -0.02)
    assert expanded_uncertainty(plain, fit) == pytest.approx(0.001)
    assert expanded_uncertainty(WithU("bore", "diameter", 30.0, 30.01, 0.02, -0.02, expanded_uncertainty=0.0031),
                                fit) == 0.0031


def _dmis_actuals(text: str) -> dict[str, list[float]]:
    joined = re.sub(r"\$\s*\n", " ", text)
    return {m.group(1): [float(x) for x in m.group(3).split(",")]
            for m in re.finditer(r"^FA\((\w+)\) = FEAT/([A-Z, ]+?),\s+([-\d., ]+)$", joined, re.M)}


def _dmis_tolerances(text: str) -> dict[str, tuple[float, str]]:
    return {m.group(1): (float(m.group(2)), m.group(3))
            for m in re.finditer(r"^TA\((\w+)\) = TOL/[A-Z0-9, ]+?, (-?[\d.]+), (INTOL|OUTOL)$", text, re.M)}


@pytest.fixture(scope="module")
def dmis_run(tmp_path_factory):
    """The sample part's program up to the sphere (26 hits), its tolerances on TOP, BORE, BOSS and SPHERE."""
    from cmm.cli import main

    qif_support.schema_or_skip()
    d = tmp_path_factory.mktemp("qifrun")
    lines = SAMPLE.read_text().splitlines()
    body = [ln for ln in lines[:lines.index("ENDMES", lines.index(next(x for x in lines if x.startswith("F(SPHERE)"))))
                                + 1] if "DID(REPORT)" not in ln]
    (d / "out").mkdir()
    program = d / "qifpart.dmi"
    program.write_text("\n".join(body + [
        "T(FLAT_A) = TOL/FLAT, 0.010", "T(DIAM_B) = TOL/DIAM, -0.020, 0.020", "T(CYL_B) = TOL/CYLCTY, 0.010",
        "T(DIAM_BOSS) = TOL/DIAM, -0.020, 0.020", "T(POS_BOSS) = TOL/POS, 3D, 0.040, DAT(A), DAT(B), DAT(C)",
        "T(DIAM_SPH) = TOL/DIAM, -0.020, 0.020", "T(PERP_B) = TOL/PERPEND, 0.020, DAT(A)",
        "T(DIST_BOSS) = TOL/DISTB, NOMINL, 43.863, -0.030, 0.030",
        "OUTPUT/FA(TOP), TA(FLAT_A)", "OUTPUT/FA(BORE), TA(DIAM_B), TA(CYL_B), TA(PERP_B)",
        "OUTPUT/FA(BORE), FA(BOSS), TA(DIST_BOSS)",
        "OUTPUT/FA(BOSS), TA(DIAM_BOSS), TA(POS_BOSS)", "OUTPUT/FA(SPHERE), TA(DIAM_SPH)", "ENDFIL", ""]))
    import os

    cwd = os.getcwd()
    os.chdir(d)
    try:
        assert main(["run", str(program), "--sessions", str(d / "sessions"), "-o", str(d / "out" / "qifpart_out.dms"),
                     "--qif"]) == 0
    finally:
        os.chdir(cwd)
    return d


def test_cmm_run_qif_is_valid_and_its_values_are_the_dmis_outputs(dmis_run):
    from cmm.journal.store import open_store, load_session

    d = dmis_run
    qif = d / "out" / "qifpart.qif"  # beside the DMIS output, named for the program
    root = qif_support.validate(qif)
    out = (d / "out" / "qifpart_out.dms").read_text()
    actuals, tols = _dmis_actuals(out), _dmis_tolerances(out)
    chars = {c["name"]: c for c in characteristics(root)}
    # sizes: the FA diameter is the measured feature's and the characteristic's value; TA(DIAM) its deviation
    items = {e.find("q:FeatureName", NS).text: e.get("id") for e in root.find("q:Features/q:FeatureItems", NS)}
    meas = {m.find("q:FeatureItemId", NS).text: m for m in root.find(".//q:MeasuredFeatures", NS)}
    for feat, label, dia_at in (("BORE", "DIAM_B", 6), ("BOSS", "DIAM_BOSS", 6), ("SPHERE", "DIAM_SPH", 3)):
        c = chars[f"{feat} diameter"]
        assert round(c["value"], 5) == pytest.approx(actuals[feat][dia_at], abs=6e-6), feat
        assert float(meas[items[feat]].find("q:Diameter", NS).text) == c["value"]
        value, verdict = tols[label]
        assert round(c["value"] - c["target"], 5) == pytest.approx(value, abs=1.1e-5), label
        assert c["status"] == ("PASS" if verdict == "INTOL" else "FAIL"), label
        assert (c["max"], c["min"]) == (0.02, -0.02)
    assert tols["DIAM_SPH"][1] == "OUTOL" and chars["SPHERE diameter"]["status"] == "FAIL"
    # form: the zone the DMIS output gives, against the DMIS tolerance
    for name, label, zone in (("TOP flatness", "FLAT_A", 0.01), ("BORE cylindricity", "CYL_B", 0.01)):
        assert round(chars[name]["value"], 5) == pytest.approx(tols[label][0], abs=1.1e-5), name
        assert chars[name]["zone"] == zone and chars[name]["status"] == "PASS"
    # the position to the datums A|B|C: the station's geometric tolerance, with its datum reference frame
    pos = next(c for c in chars.values() if c["type"] == "Position" and c["drf"] is not None)
    assert pos["features"] == ["BOSS"] and round(pos["value"], 5) == pytest.approx(tols["POS_BOSS"][0], abs=1.1e-5)
    assert {x.find("q:DatumLabel", NS).text for x in root.findall(".//q:DatumDefinition", NS)} == {"A", "B", "C"}
    # the DMIS tolerances the report has no row for: their TA values and verdicts, after the report's
    perp = chars["BORE perpendicularity PERPEND T(PERP_B)"]
    assert perp["type"] == "Perpendicularity" and perp["zone"] == 0.02 and perp["features"] == ["BORE"]
    assert round(perp["value"], 5) == pytest.approx(tols["PERP_B"][0], abs=1.1e-5)
    assert perp["status"] == ("PASS" if tols["PERP_B"][1] == "INTOL" else "FAIL")
    dist = chars["BORE-BOSS distance DISTB T(DIST_BOSS)"]
    assert dist["type"] == "DistanceBetween" and dist["features"] == ["BORE", "BOSS"] and dist["target"] == 43.863
    assert round(dist["value"] - dist["target"], 5) == pytest.approx(tols["DIST_BOSS"][0], abs=1.1e-5)
    assert (dist["max"], dist["min"]) == (0.03, -0.03) and dist["status"] == "PASS" == \
        ("PASS" if tols["DIST_BOSS"][1] == "INTOL" else "FAIL")
    # the run: program, station, the report beside it, the overall verdict
    assert root.find(".//q:InspectionProgram/q:File/q:Name", NS).text == "qifpart.dmi"
    assert root.find(".//q:ExternalFileReference/q:URI", NS).text.endswith("qifpart_report.html")
    assert root.find(".//q:InspectionStatus/q:InspectionStatusEnum", NS).text == "FAIL"
    # against the station's report of the same session, row by row
    store = open_store(str(d / "sessions"))
    (info,) = store.list()
    s = load_session(store, info.name)
    from cmm.session.export import resolve_part_mesh

    check_against_csv(root, features_csv(s, mesh=resolve_part_mesh(s)))


def test_sessions_export_qif_of_a_run_and_of_a_reevaluated_session(dmis_run, tmp_path, capsys):
    from cmm.cli import main
    from cmm.journal.store import open_store, load_session

    sessions = str(dmis_run / "sessions")
    (info,) = open_store(sessions).list()
    target = tmp_path / "export.qif"
    assert main(["sessions", "--store", sessions, "export", info.name, "--qif", str(target)]) == 0
    assert "QIF 3 results" in capsys.readouterr().out
    exported = qif_support.validate(target)
    run = qif_support.validate(dmis_run / "out" / "qifpart.qif")
    # the same session: the same characteristics and values (the program is read from the session's notes), the
    # DMIS-only tolerances (PERPEND, DISTB: kept in the session by the run) included, with their limits
    keys = ("name", "type", "value", "status", "target", "max", "min", "zone", "features")
    assert [tuple(c[k] for k in keys) for c in characteristics(exported)] == \
        [tuple(c[k] for k in keys) for c in characteristics(run)]
    assert {"BORE perpendicularity PERPEND T(PERP_B)", "BORE-BOSS distance DISTB T(DIST_BOSS)"} <= \
        {c["name"] for c in characteristics(exported)}
    assert exported.find(".//q:InspectionProgram/q:File/q:Name", NS).text == "qifpart.dmi"
    # re-evaluated with another tip radius: a new session, a valid document with its own QPId and values
    new = f"{info.name}-r"
    assert main(["sessions", "--store", sessions, "reevaluate", info.name, new, "--tip-radius", "1.01"]) == 0
    assert main(["sessions", "--store", sessions, "export", new, "--qif", str(tmp_path / "r.qif")]) == 0
    derived = qif_support.validate(tmp_path / "r.qif")
    # the DMIS-only tolerances evaluated again on the refitted features (tests/test_qif_reevaluate.py: their values)
    assert [c["name"] for c in characteristics(derived) if DMIS_ONLY.search(c["name"])] == \
        [c["name"] for c in characteristics(exported) if DMIS_ONLY.search(c["name"])]
    assert derived.find(".//q:NotedEvents", NS) is None  # nothing left out
    assert derived.find("q:QPId", NS).text != exported.find("q:QPId", NS).text
    s = load_session(open_store(sessions), new)
    from cmm.session.export import resolve_part_mesh

    chars = check_against_csv(derived, features_csv(s, mesh=resolve_part_mesh(s)))
    before = {c["name"]: c["value"] for c in characteristics(exported)}
    bore = next(c for c in chars if c["name"] == "BORE diameter")
    assert not math.isclose(bore["value"], before["BORE diameter"], abs_tol=1e-4)  # the tip is 0.01 mm bigger


def test_an_auto_measured_session_on_the_station_is_valid_qif_with_the_reports_values(tmp_path):
    """Auto-measure on the station (the operator's clicks on the block, a 3-2-1 alignment, a constructed distance):
    the QIF document of its session validates and carries the report's characteristics, the part from CAD."""
    import session_support as sup

    from cmm.session.export import resolve_part_mesh
    from cmm.journal.store import open_session

    qif_support.schema_or_skip()
    gen = sup.sim_station(tmp_path, "auto")
    st = next(gen)
    try:
        sup.teach_block(st.measurement, sup.BLOCK_FACES[:5])
        st.measurement.set_info(operator="R. Quality")
        path = st.measurement.journal.path
    finally:
        gen.close()
    s = open_session(path)
    mesh = resolve_part_mesh(s)
    root = qif_support.validate(write_qif(s, tmp_path / "auto.qif", mesh=mesh))
    chars = check_against_csv(root, features_csv(s, mesh=mesh))
    assert {"DistanceBetween", "Diameter", "Flatness", "UserDefinedLinear"} <= {c["type"] for c in chars}
    assert root.find(".//q:InspectionOperator/q:Name", NS).text == "R. Quality"
    assert len(root.findall(".//q:Part/q:FeatureNominalIds/q:Id", NS)) == 5  # every feature's nominal from CAD


def test_a_routine_run_written_as_the_report_tab_does_is_valid_qif_with_the_reports_values(tmp_path):
    """A routine taught on the block and run on the station: the Report tab's QIF (the session worker's writer) of
    the run's session validates and carries the report's characteristics, the routine as the program."""
    import session_support as sup

    from cmm.journal.store import load_session, open_session, open_store
    from cmm.measurement.routine import teach_routine
    from cmm.measurement.routine_host import StationRoutineHost
    from cmm.measurement.routine_run import RoutineRun
    from cmm.session import worker
    from cmm.session.export import resolve_part_mesh

    qif_support.schema_or_skip()
    gen = sup.sim_station(tmp_path, "teach")
    st = next(gen)
    try:
        model = st.measurement
        sup.teach_block(model, sup.BLOCK_FACES[:5])
        routine = teach_routine(open_session(model.journal.path), name="block", part_mesh=model.part.mesh,
                                part_nominals=model.part.nominal_features)
        routine.steps[0]["manual"] = None  # the part is aligned: the datums are measured automatically
        progress = RoutineRun(routine, StationRoutineHost(model, st.controller), part_name="R-1").run()
        assert progress.state == "done"
        sessions = model.session_dir
    finally:
        gen.close()
    name = Path(str(progress.session)).stem
    (path,) = worker.qif(sessions, name, tmp_path / "exports")
    root = qif_support.validate(path)
    s = load_session(open_store(str(sessions)), name)
    chars = check_against_csv(root, features_csv(s, mesh=resolve_part_mesh(s)))
    assert {"Diameter", "Flatness", "DistanceBetween"} <= {c["type"] for c in chars}
    assert root.find(".//q:InspectionProgram/q:File/q:Name", NS).text == "block"
