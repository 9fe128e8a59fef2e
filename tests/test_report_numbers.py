"""Every number reaches the report unchanged: one session with a feature of every kind and every GD&T
characteristic; the feature tree (live model), the journal's records, the HTML report, the CSV and the JSON
export give the same numbers (the same Characteristic objects, the same fitted geometry to the last bit).

The hits are recorded directly (surface points of the sample part with a known small form, their tip centres a
probe radius off the surface) on the simulator's machine and probe settings: probing 60 hits on the simulator
takes minutes, and what is under test here is the path from the fit to the report, not the probing."""

from __future__ import annotations

import json
import math
import time
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
import session_support as ss

from cmm.machine.probing import Hit
from cmm.measurement.model import Part
from cmm.measurement.recording import record
from cmm.metrology.compensation import PretravelModel
from cmm.metrology.gdt import CHARACTERISTICS
from cmm.session.export import session_json
from cmm.session.gdt_session import session_gdt
from cmm.session.report import features_csv, render
from cmm.journal.store import DirectoryStore, load_session
from cmm.sim.cmm_sim import NOMINAL_PART_POSE
from cmm.api import CommandAPI
from cmm.measurement.queries import register_queries
from cmm.ui.panel_features import feature_chars, tree_html

T = NOMINAL_PART_POSE


def _queries(model):
    """The measurement's queries on a bare model (no control core): the command API with only them registered."""
    api = CommandAPI()
    register_queries(api, model)
    return api


def ring(centre, radius, z, k, phase=0.0, inward=False):
    """k (point, outward normal) on a circle of the sample part (part coordinates)."""
    out = []
    for a in np.linspace(0, 2 * np.pi, k, endpoint=False) + phase:
        n = np.array([math.cos(a), math.sin(a), 0.0])
        out.append((np.array([centre[0], centre[1], z]) + radius * n, -n if inward else n))
    return out


def surfaces():
    """(name, kind, [(part point, outward normal)]) of a feature of every kind."""
    grid = lambda f, a, b: [f(x, y) for x in a for y in b]  # noqa: E731
    top = grid(lambda x, y: (np.array([x, y, 40.0]), np.array([0, 0, 1.0])), (8, 50, 112), (8, 72))
    front = grid(lambda x, z: (np.array([x, 0.0, z]), np.array([0, -1.0, 0])), (10, 60, 110), (8, 30))
    left = grid(lambda y, z: (np.array([0.0, y, z]), np.array([-1.0, 0, 0])), (10, 70), (8, 30))
    line = [(np.array([x, 0.0, 20.0]), np.array([0, -1.0, 0])) for x in (15, 35, 55, 75, 95)]
    bore = ring((30, 40), 15, 8, 6, inward=True) + ring((30, 40), 15, 32, 6, 0.5, inward=True)
    bore_low, bore_high = ring((30, 40), 15, 4, 6, 0.2, inward=True), ring((30, 40), 15, 36, 6, 0.3, inward=True)
    boss = ring((70, 22), 10, 44, 5) + ring((70, 22), 10, 52, 5, 0.6)
    boss_ring = ring((70, 22), 10, 48, 6, 0.3)
    dome = [(np.array([70, 58, 49.0]), np.array([0, 0, 1.0]))]
    for a in np.radians([20, 110, 200, 290]):
        n = np.array([math.sin(math.radians(50)) * math.cos(a), math.sin(math.radians(50)) * math.sin(a),
                      math.cos(math.radians(50))])
        dome.append((np.array([70, 58, 39.0]) + 10 * n, n))
    half = math.atan(0.5)
    cone = []
    for z, phase in ((42.0, 0.0), (50.0, 0.4)):
        for p, radial in ring((100, 40), (64 - z) * 0.5, z, 5, phase):
            cone.append((p, math.cos(half) * radial + math.sin(half) * np.array([0, 0, 1.0])))
    point = [(np.array([20.0, 60.0, 40.0]), np.array([0, 0, 1.0]))]
    return [("top", "plane", top), ("front", "plane", front), ("left", "plane", left), ("edge", "line", line),
            ("bore", "cylinder", bore), ("bore low", "circle", bore_low), ("bore high", "circle", bore_high),
            ("boss", "cylinder", boss), ("boss ring", "circle", boss_ring), ("dome", "sphere", dome),
            ("cone", "cone", cone), ("spot", "point", point)]


def fit_surfaces(model, prober, wanted=None):
    """Record every surface's hits in ``model`` and fit (least squares) those named in ``wanted`` (all if None)."""
    feats = {}
    k = 0
    for name, kind, pts in surfaces():
        ids = []
        for p, n in pts:
            ids.append(model.add_hit(hit_on(p, n, k, prober.settings.tip_radius)))
            k += 1
        if wanted is None or name in wanted:
            feats[name] = model.fit_feature(kind, ids, "ls", name)
    return feats


def hit_on(p, n, k, tip):
    """The hit at part point p (outward normal n), off the surface by a small known form (k-th hit)."""
    form = 0.003 * math.sin(1.7 * k + 0.4)
    pm = T[:3, :3] @ (p + form * n) + T[:3, 3]
    nm = T[:3, :3] @ n
    return Hit(counts=(0, 0, 0), machine=tuple(pm + tip * nm), approach=tuple(-nm), speed=5.0, time=time.time(),
               point=tuple(pm))


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    sim, machine, prober = ss.setup()
    prober.settings.pretravel = PretravelModel()  # the recorded tip centres are the corrected ones
    store = DirectoryStore(tmp_path_factory.mktemp("numbers"))
    part = Part("sample part", sim.part_mesh, T.copy(), dict(sim.nominal_features))
    model = record(store.create("numbers"), machine, prober, part, port="in-process")
    feats = fit_surfaces(model, prober)
    for label, name in (("A", "top"), ("B", "front"), ("C", "left"), ("D", "bore"), ("E", "bore low"),
                        ("F", "bore high"), ("G", "boss")):
        model.define_datum(label, feats[name].id)
    i = lambda name: feats[name].id  # noqa: E731
    model.define_gdt("flatness", i("top"), 0.01)
    model.define_gdt("straightness", i("edge"), 0.01)
    model.define_gdt("circularity", i("boss ring"), 0.01)
    model.define_gdt("cylindricity", i("boss"), 0.01)
    model.define_gdt("parallelism", i("edge"), 0.02, "A")
    model.define_gdt("perpendicularity", i("boss"), 0.02, "A")
    model.define_gdt("angularity", i("edge"), 0.02, "C", angle=90.0)
    model.define_gdt("position", i("bore"), 0.05, "A|B|C")
    model.define_gdt("position", i("boss"), 0.05, "A|B|C", material="MMC")
    # a hole at MMC with its own size limits (-0.01 / +0.05 on D30), against the boss referenced at MMB by this
    # frame (its datum G is RFS elsewhere)
    model.set_feature_nominal(i("bore"), tolerance={"size_lower": -0.01, "size_upper": 0.05})
    model.define_gdt("position", i("bore"), 0.05, "A|G", material="MMC", datum_modifiers={"G": "MMB"},
                     name="bore at MMC to the boss")
    model.define_gdt("concentricity", i("boss ring"), 0.02, "G")
    model.define_gdt("coaxiality", i("bore"), 0.02, "E-F")
    model.define_gdt("circular runout", i("bore"), 0.02, "E-F")
    model.define_gdt("total runout", i("bore"), 0.02, "E-F")
    model.define_gdt("profile of a surface", i("cone"), 0.02, "A|B|C")
    model.define_gdt("profile of a line", i("edge"), 0.02)
    model.define_gdt("position", i("bore"), 0.5, "A|B|C", pattern=[i("bore"), i("boss")],
                     composite={"tolerance": 0.05, "datums": ["A"]})
    model.construct_feature("distance", i("bore"), i("boss"), name="bore to boss")
    live_features = {f.id: f for f in model.features.values()}
    live_constructed = {c.id: c for c in model.constructed.values()}
    live_probes = {fid: model.feature_probe(f) for fid, f in live_features.items()}
    live_gdt = model.gdt_characteristics()
    tree = tree_html(_queries(model))
    model.close()
    machine.close()
    s = load_session(store, "numbers")
    mesh = sim.part_mesh
    # each output once (each evaluates the tolerances again, from the journal)
    yield SimpleNamespace(features=live_features, constructed=live_constructed, probes=live_probes, gdt=live_gdt,
                          tree=tree, session=s, mesh=mesh,
                          json=json.loads(json.dumps(session_json(s, mesh=mesh), allow_nan=False)),
                          html=render(s, mesh=mesh),
                          csv=[r.split(",") for r in features_csv(s, mesh=mesh).splitlines()[1:]])


def test_every_feature_kind_reaches_the_report_unchanged(measured):
    s = measured.session
    exported, html, csv_rows = measured.json, measured.html, measured.csv
    kinds = set()
    for fid, live in measured.features.items():
        kinds.add(live.kind)
        rec = s.state.features[fid]
        # the journal's record is the live result: every fitted number to the last bit
        summary = json.loads(json.dumps(live.result.summary()))
        exp = next(f for f in exported["features"] if f["id"] == fid)
        numbers = {k: v for k, v in summary.items() if k not in ("kind", "method")}
        assert numbers and all(rec.fit[k] == v and exp[k] == v for k, v in numbers.items()), live.name
        chars = feature_chars(live)
        assert chars or live.kind == "point", live.name  # a point has no form and no size: its XYZ only
        assert rec.characteristics(live.tolerance or {}) == chars, live.name
        for c in chars:
            if c.actual is None:
                continue
            assert f"{c.actual:.4f}" in measured.tree and f"{c.actual:.4f}" in html, (live.name, c.name)
            row = next(r for r in csv_rows if r[0] == live.name and r[4] == c.name)
            assert row[9] == f"{c.actual:.6f}" and row[12] == c.verdict, (live.name, c.name)
    assert kinds == {"plane", "line", "circle", "cylinder", "sphere", "cone", "point"}


def test_the_journal_holds_the_live_features_records(measured):
    """What replay and the report read of a feature or a construction is the record the live one gives, field by
    field (its fit summary to the last bit); a construction's characteristics are the tree's, in the report."""
    st = measured.session.state
    assert st.features.keys() == measured.features.keys() and st.constructed.keys() == measured.constructed.keys()
    for fid, live in measured.features.items():
        assert replace(live.record(measured.probes[fid]), seq=st.features[fid].seq) == st.features[fid], live.name
    for cid, live in measured.constructed.items():
        rec = st.constructed[cid]
        assert replace(live.record(), seq=rec.seq) == rec and rec.operands == tuple(live.operands)
        (c,) = live.record().characteristics()
        assert c == rec.characteristics()[0] and c.name == "distance" and c.actual is not None
        assert f"{c.actual:.4f}" in measured.tree and f"{c.actual:.4f}" in measured.html
        row = next(r for r in measured.csv if r[0] == "bore to boss")
        assert row[1] == "constructed" and row[2] == "distance" and row[9] == f"{c.actual:.6f}"


def test_every_gdt_characteristic_reaches_the_report_unchanged(measured):
    s = measured.session
    rows = session_gdt(s, measured.mesh)
    assert [c for _, c in rows] == [c for _, c in measured.gdt]  # the same Characteristic, field by field
    assert {d["characteristic"] for d, _ in rows} == set(CHARACTERISTICS) - {"coaxiality"} | {"coaxiality"}
    assert all(c.actual is not None for _, c in rows), [c.note for _, c in rows if c.actual is None]
    exported, html = measured.json["gdt"], measured.html
    csv_rows = [r for r in measured.csv if r[1] == "gdt"]
    assert len(exported) == len(rows) == len(csv_rows) == 19  # 17 tolerances, the composite has 3 rows
    for (d, c), e, r in zip(rows, exported, csv_rows):
        assert e["value"] == c.actual and e["allowed"] == c.upper and e["drf"] == c.datums, c.note
        assert e["feature_name"] == c.feature and e["result"] == c.verdict
        assert f"{c.actual:.4f}" in html and f"{c.actual:.4f}" in measured.tree, c.note
        assert r[0] == c.feature and r[9] == f"{c.actual:.6f}" and r[12] == c.verdict
    # position at MMC: the bonus is the bore's departure from its own MMC size (30 - 0.01), in every output
    (d, c), e = next((x, e) for x, e in zip(rows, exported) if x[0]["name"] == "bore at MMC to the boss")
    bore = measured.features[d["feature"]]
    bonus = 2.0 * bore.result.geometry()["radius"] - 29.99
    assert bonus > 0.005 and c.upper == pytest.approx(0.05 + bonus, abs=1e-12) and e["allowed"] == c.upper
    assert "⊕ ⌀0.0500(M) | A|G(M)" in html and f"<td>0.0500</td><td>{bonus:.4f}</td><td>{c.actual:.4f}</td>" in html
    assert "G(M) = boss" in html
    composite = [c for d, c in rows if "composite" in d]
    assert [c.feature for c in composite] == ["bore", "boss", "pattern of 2"]
    # each tier its own U (the same propagation as any position), in the tree's and the CSV's rows alike
    assert all(c.uncertainty is not None and c.uncertainty > 0 for c in composite), [c.uncertainty_why for c in composite]
    assert [r[14] for r in csv_rows if r[0] in ("pattern of 2",)] == [f"{composite[2].uncertainty:.6f}"]
    # the profiles too: their points moved through their best fit to the mesh (the edge, a line, has no budget of
    # its own: the station's default sources)
    profiles = [c for d, c in rows if d["characteristic"].startswith("profile")]
    assert len(profiles) == 2 and all(c.uncertainty and c.uncertainty > 0 for c in profiles), \
        [c.uncertainty_why for c in profiles]
    assert "⊕ ⌀0.5000 | A|B|C / ⌀0.0500 | A" in html and "E = bore low; F = bore high" in html


def test_a_criterion_cylinders_proof_reaches_the_tree_the_journal_and_the_report(tmp_path):
    """A cylinder fitted by MCC carries the domain its optimum was searched (and proven or not) in: the tree
    states it briefly, the journal's record keeps it, the report states it in full, all from the same record."""
    from cmm.metrology.features import proof_text

    sim, machine, prober = ss.setup()
    prober.settings.pretravel = PretravelModel()
    store = DirectoryStore(tmp_path)
    model = record(store.create("proof"), machine, prober, Part("sample part", sim.part_mesh, T.copy(),
                                                                dict(sim.nominal_features)), port="in-process")
    pts = dict((name, p) for name, _, p in surfaces())["boss"]
    ids = [model.add_hit(hit_on(p, n, k, prober.settings.tip_radius)) for k, (p, n) in enumerate(pts)]
    feature = model.fit_feature("cylinder", ids, "mcc", "boss mcc")
    proof = feature.result.proof
    assert proof is not None and proof["cone_deg"] > 0 and proof["cells"] > 0
    tree = tree_html(_queries(model))
    model.close()
    machine.close()
    assert proof_text(proof, short=True) in tree
    s = load_session(store, "proof")
    (rec,) = s.features.values()
    assert rec.fit["proof"] == proof
    assert proof_text(proof) in render(s, mesh=sim.part_mesh)
