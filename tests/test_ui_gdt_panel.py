"""The Features tab's "Datums and GD&T" actions as an operator types them: datum targets (hit ids), a common datum
"E-F", a composite position (pattern ids, lower tier); refusals are shown in words and record nothing."""

from __future__ import annotations

import pytest
import session_support as ss
from test_report_numbers import T, fit_surfaces

from cmm.control import Controller
from cmm.control.access import Control
from cmm.measurement.model import Part
from cmm.measurement.recording import record
from cmm.metrology.compensation import PretravelModel
from cmm.journal.store import DirectoryStore, load_session
from cmm.measurement.queries import register_queries
from cmm.measurement.verbs import register_measurement_verbs
from cmm.ui.context import PanelContext
from cmm.ui.panel_features import FeaturesPanel, tree_html


@pytest.fixture
def panel(tmp_path):
    sim, machine, prober = ss.setup()
    prober.settings.pretravel = PretravelModel()
    store = DirectoryStore(tmp_path)
    model = record(store.create("panel"), machine, prober,
                   Part("sample part", sim.part_mesh, T.copy(), dict(sim.nominal_features)), port="in-process")
    wanted = {"top", "front", "left", "bore", "bore low", "bore high", "boss"}
    fit_surfaces(model, prober, wanted)
    control = Control()
    control.take("operator", is_local=True)
    controller = Controller(machine, prober)  # the tab's actions are the command API's verbs, checked by the holder
    controller.use_policy_of(control)
    register_measurement_verbs(controller, model)
    register_queries(controller.commands, model)  # the tab reads the model through the API's queries
    ctx = PanelContext(controller.commands, control, None, client_id="operator", is_local=True)
    yield FeaturesPanel(ctx), model, store
    model.close()
    machine.close()


def test_targets_common_datum_and_composite_from_the_tab(panel):
    p, model, store = panel
    fid = {f.name: f.id for f in model.features.values()}
    top_hits = model.features[fid["top"]].hit_ids
    front_hits = model.features[fid["front"]].hit_ids
    left_hits = model.features[fid["left"]].hit_ids
    # datum targets typed as hit ids; B, C from the whole faces
    p._datum("A", f"{fid['top']} top", "RFS", f"{top_hits[0]} {top_hits[2]} {top_hits[4]}")
    p._datum("B", f"{fid['front']} front", "RFS", f"{front_hits[0]}, {front_hits[3]}")
    p._datum("C", f"{fid['left']} left", "RFS", f"{left_hits[1]}")
    p._datum("E", f"{fid['bore low']} bore low", "RFS")
    p._datum("F", f"{fid['bore high']} bore high", "RFS")
    assert model.datums["A"]["targets"] == [top_hits[0], top_hits[2], top_hits[4]]
    assert p.ctx.messages == [], p.ctx.messages
    d, c = p._gdt("coaxiality", f"{fid['bore']} bore", 0.02, "E-F", "RFS", 0.0, "radial")
    assert c.datums == "E-F" and c.actual is not None
    d, c = p._gdt("position", f"{fid['bore']} bore", 0.5, "A|B|C", "RFS", 0.0, "radial",
                  f"{fid['bore']} {fid['boss']}", 0.05, "A")
    assert d["pattern"] == [fid["bore"], fid["boss"]] and d["composite"] == {"tolerance": 0.05, "datums": ["A"]}
    rows = [r for dd, r in model.gdt_characteristics() if dd["id"] == d["id"]]
    assert [r.feature for r in rows] == ["bore", "boss", "pattern of 2"] and rows[0] == c
    tree = tree_html(p.ctx.query)
    assert f"{d['id']} pattern of 2" in tree and f"{rows[2].actual:.4f}" in tree
    # refused in words, nothing recorded: two targets on the primary, a composite with a larger lower tier
    n_defs = len(model.gdt)
    p._datum("G", f"{fid['top']} top", "RFS", f"{top_hits[0]} {top_hits[1]}")
    p._gdt("position", f"{fid['bore']} bore", 0.5, "G|B", "RFS", 0.0, "radial")
    assert "datum G has 2 target point(s): as the primary datum a plane needs 3" in p.ctx.messages[-1][2]
    p._gdt("position", f"{fid['bore']} bore", 0.05, "A|B|C", "RFS", 0.0, "radial", f"{fid['boss']}", 0.5, "A")
    assert "feature-relating (lower) tolerance 0.5 must be smaller" in p.ctx.messages[-1][2]
    p._datum("H", f"{fid['top']} top", "RFS", "1 x 3")
    assert "'x' is not a hit number" in p.ctx.messages[-1][2] and "H" not in model.datums
    assert len(model.gdt) == n_defs
    model.journal.close()
    s = load_session(store, "panel")
    assert s.state.datums["A"]["targets"] == [top_hits[0], top_hits[2], top_hits[4]]
    assert s.state.gdt[d["id"]]["composite"] == {"tolerance": 0.05, "datums": ["A"]}


def test_unequally_disposed_profile_from_the_tab(panel):
    """A profile's zone offset (ISO 1101 UZ) typed in the tab: in the definition, the journal and the report's
    frame ("UZ-0.0020"); the top's profile without datums floats onto the offset zone (the same value as the
    equally disposed one); an offset beyond half the zone is refused in words."""
    from cmm.session.report import render

    p, model, store = panel
    top = next(f.id for f in model.features.values() if f.name == "top")
    _, equal = p._gdt("profile of a surface", f"{top} top", 0.02, "", "RFS", 0.0, "radial")
    d, c = p._gdt("profile of a surface", f"{top} top", 0.02, "", "RFS", 0.0, "radial", "", 0.0, "", -0.002)
    assert d["offset"] == -0.002 and "zone offset -0.0020 mm (UZ)" in c.note
    assert c.actual == pytest.approx(equal.actual, abs=1e-6)
    n_defs = len(model.gdt)
    p._gdt("profile of a surface", f"{top} top", 0.02, "", "RFS", 0.0, "radial", "", 0.0, "", 0.02)
    assert "moves the profile zone of 0.02 off the nominal surface" in p.ctx.messages[-1][2]
    assert len(model.gdt) == n_defs
    model.journal.close()
    s = load_session(store, "panel")
    assert s.state.gdt[d["id"]]["offset"] == -0.002
    assert "⌓ 0.0200 UZ-0.0020" in render(s, mesh=model.part.mesh)
