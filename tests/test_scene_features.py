"""Fitted features in the 3-D view: thin outlines and translucent patches at the measured extent, hidden and shown
per feature and per kind from the Features tab, the selected one stronger, a fit's check alternative drawn
as a dashed ghost beside it, and the face a click picked highlighted in the tab's own view. Checked on viser's
server-side scene handles of a station on the simulator."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
import ui_support

pytest.importorskip("viser")

from cmm.machine.probing import Hit  # noqa: E402
from cmm.metrology.pick import NominalFeature  # noqa: E402
from cmm.ui.feature_drawing import PATCH_OPACITY, feature_drawing  # noqa: E402
from cmm.ui.panel_features import tree_html  # noqa: E402
from cmm.ui.pick_highlight import HIGHLIGHT_OPACITY, OFFSET_MM  # noqa: E402
from cmm.ui.scene import SCALE  # noqa: E402


@pytest.fixture(scope="module")
def app(module_stations):
    return module_stations.app(module_stations.station("scene", home=False), pendant=False, ask_name=False)


def _hits(model, surface_points, approaches):
    """Hits whose tip touched ``surface_points`` coming along ``approaches`` (what the prober records)."""
    r = model.prober.settings.tip_radius
    ids = []
    for p, u in zip(np.asarray(surface_points, float), np.asarray(approaches, float)):
        u = u / np.linalg.norm(u)
        centre = p - r * u
        ids.append(model.add_hit(Hit((0, 0, 0), tuple(centre), tuple(u), 5.0, 0.0, tuple(p))))
    return ids


def _mm(view, node_points):
    return np.asarray(node_points, float).reshape(-1, 3) / SCALE + view.origin_mm


def test_a_plane_is_a_translucent_patch_over_its_hits_not_a_plate():
    hits = np.array([[0, 0, 40.0], [30, 0, 40.0], [30, 20, 40.0], [0, 20, 40.0], [15, 10, 40.0]])
    d = feature_drawing("plane", {"point": [15, 10, 40.0], "normal": [0, 0, 1.0]}, hits)
    lo, hi = d.patch.vertices.min(axis=0), d.patch.vertices.max(axis=0)
    assert np.all(lo[:2] >= [-1.5, -1.5]) and np.all(hi[:2] <= [31.5, 21.5])  # the hits' hull and 1 mm
    assert d.patch.area == pytest.approx(30 * 20, rel=0.25) and d.opacity <= PATCH_OPACITY
    ends = d.lines.reshape(-1, 3)
    assert np.allclose(ends[:, 2], 40.0) and len(d.lines) == 4  # the outline: the hull's four sides


def test_cylinders_and_circles_are_outlines_at_the_measured_radius_and_extent():
    hits = np.array([[10, 0, 5.0], [0, 10, 5.0], [-10, 0, 25.0], [0, -10, 25.0]])
    d = feature_drawing("cylinder", {"point": [0, 0, 0.0], "direction": [0, 0, 1.0], "radius": 10.0}, hits)
    ends = d.lines.reshape(-1, 3)
    r = np.hypot(ends[:, 0], ends[:, 1])
    on_axis = r < 1e-9  # the dashed axis line
    assert np.allclose(r[~on_axis], 10.0) and ends[:, 2].min() == pytest.approx(5.0) \
        and ends[:, 2].max() == pytest.approx(25.0)
    c = feature_drawing("circle", {"center": [1, 2, 3.0], "normal": [0, 0, 1.0], "radius": 15.0}, hits)
    assert np.allclose(np.linalg.norm(c.lines.reshape(-1, 3) - [1, 2, 3.0], axis=1), 15.0)
    s = feature_drawing("sphere", {"center": [0, 0, 0.0], "radius": 5.0}, hits)
    assert s.opacity <= PATCH_OPACITY and np.allclose(np.linalg.norm(s.lines.reshape(-1, 3), axis=1), 5.0)


def test_features_hide_and_show_per_feature_and_kind_and_the_selection_stands_out(app):
    model, view = app.station.measurement, app.view
    capp = app.add_client(client_id="show", is_local=True)
    assert capp.take_control()
    top = [[100, 100, 40.0], [160, 100, 40.0], [160, 150, 40.0], [100, 150, 40.0]]
    plane = model.fit_feature("plane", _hits(model, top, [[0, 0, -1]] * 4), name="TOP")
    ring = [[130 + 15 * np.cos(a), 125 + 15 * np.sin(a), 30.0] for a in np.radians([0, 90, 180, 270])]
    circle = model.fit_feature("circle", _hits(model, ring, [[np.cos(a), np.sin(a), 0] for a in
                                                              np.radians([0, 90, 180, 270])]), name="bore")
    app.redraw()
    pn, cn = view._feature_nodes[plane.id], view._feature_nodes[circle.id]
    assert pn.patch.opacity <= PATCH_OPACITY and cn.patch.opacity <= 0.15  # nothing opaque over the part
    patch = _mm(view, pn.patch.vertices)
    assert patch[:, 0].min() > 98 and patch[:, 0].max() < 162  # the measured extent, not a plate
    assert np.allclose(np.linalg.norm(_mm(view, cn.outline.points)[:, :2] - [130, 125], axis=1), 15.0, atol=0.01)
    assert pn.visible and cn.visible
    # per feature: the Features tab's Show checkbox for the selected feature
    capp.select_feature(circle.id)
    assert cn.outline.thickness > pn.outline.thickness and cn.patch.opacity > 0.12  # selected: stronger
    capp.features.show_selected(False)
    assert not cn.visible and pn.visible
    assert "(hidden)" in tree_html(app.api, circle.id, capp.features.hidden())
    # per kind: planes off, then Show all
    capp.features.show_kind("plane", False)
    assert not pn.visible and not cn.visible
    capp.features.show_all()
    assert pn.visible and cn.visible
    # the choice is kept when the feature is refit (a redraw)
    view.show_feature(plane.id, False)
    model.refit_feature(plane.id, plane.hit_ids[:3])
    app.redraw()
    assert view._feature_nodes[plane.id] is not pn and not view._feature_nodes[plane.id].visible
    view.show_all()


def test_each_feature_row_has_its_own_show_checkbox(app):
    """Show > Each feature: a checkbox per fitted feature, labelled as its tree row, added and removed with the
    features; unticking one hides that feature only (and the tree says so), whichever is selected; hiding a kind
    leaves the rows' own choice as it was."""
    model, view = app.station.measurement, app.view
    capp = app.add_client(client_id="rows", is_local=True)
    assert capp.take_control()
    capp.features.build(app.server.gui)  # the tab's widgets (a headless client has none), on the server's GUI
    top = [[300, 100, 40.0], [360, 100, 40.0], [360, 150, 40.0], [300, 150, 40.0]]
    a = model.fit_feature("plane", _hits(model, top, [[0, 0, -1]] * 4), name="A")
    b = model.fit_feature("plane", _hits(model, [[x, y, 30.0] for x, y, _ in top], [[0, 0, -1]] * 4), name="B")
    app.redraw()
    capp.features.refresh()
    rows = capp.features.rows
    assert {a.id, b.id} <= set(rows) and rows[a.id].label == f"{a.id} A" and rows[b.id].label == f"{b.id} B"
    assert rows[a.id].value and rows[b.id].value
    capp.select_feature(b.id)  # the selection plays no part: each row is its own feature
    rows[a.id].value = False  # what unticking it in the page does (viser calls the row's update callback)
    assert not view._feature_nodes[a.id].visible and view._feature_nodes[b.id].visible
    capp.features.refresh()
    tree = tree_html(app.api, b.id, capp.features.hidden())
    row_a = next(r for r in tree.split("<tr") if f"data-feature='{a.id}'" in r)
    assert "(hidden)" in row_a and "(hidden)" not in next(r for r in tree.split("<tr") if f"data-feature='{b.id}'" in r)
    # planes hidden as a kind: both are hidden, the rows keep their own choice; planes shown: only A stays hidden
    capp.features.show_kind("plane", False)
    capp.features.refresh()
    assert not view._feature_nodes[b.id].visible and rows[b.id].value and not rows[a.id].value
    capp.features.show_kind("plane", True)
    assert view._feature_nodes[b.id].visible and not view._feature_nodes[a.id].visible
    # another tab's choice shows in this tab's rows; a deleted feature's row goes
    other = app.add_client(client_id="rows-2", is_local=True)
    other.features.build(app.server.gui)
    other.features.refresh()
    assert not other.features.rows[a.id].value and other.features.rows[b.id].value
    rows[a.id].value = True
    other.features.refresh()
    assert other.features.rows[a.id].value and view._feature_nodes[a.id].visible
    model.delete_feature(b.id)
    capp.features.refresh()
    assert b.id not in capp.features.rows and a.id in capp.features.rows
    model.delete_feature(a.id)
    view.show_all()


def test_a_check_alternative_is_drawn_as_a_dashed_ghost(app):
    """Two rings of four hits at the same angles: the nominal's upright cylinder is reported, the cylinder lying
    across the axis fits better and is the alternative to check (see test_fit_ls)."""
    model, view = app.station.measurement, app.view
    far = np.array([200.0, 150.0, 30.0])
    pts, app_dirs = [], []
    for z, r in ((3.0, 10.01), (-3.0, 9.99)):
        for a in np.radians([45, 135, 225, 315]):
            u = np.array([np.cos(a), np.sin(a), 0.0])
            pts.append(far + [r * u[0], r * u[1], z])
            app_dirs.append(-u)  # a boss: the probe comes in towards the axis
    nominal = NominalFeature("cylinder", {"point": far, "direction": [0, 0, 1.0], "radius": 10.0})
    f = model.fit_feature("cylinder", _hits(model, pts, app_dirs), name="boss", nominal=nominal)
    assert f.result.alternative is not None
    app.redraw()
    node = view._feature_nodes[f.id]
    assert node.ghost is not None
    ghost = _mm(view, node.ghost.points).reshape(-1, 2, 3)
    alt = f.result.alternative.geometry()
    axis = np.asarray(alt["direction"], float)
    rel = ghost.reshape(-1, 3) - np.asarray(alt["point"], float)
    radial = np.linalg.norm(rel - np.outer(rel @ axis, axis), axis=1)
    assert np.mean(np.isclose(radial, alt["radius"], atol=0.01)) > 0.5  # the ghost's rings lie on the alternative
    lengths = np.linalg.norm(ghost[:, 1] - ghost[:, 0], axis=1)
    assert lengths.max() < 1.0  # dashed: short dashes, no long lines
    assert tuple(node.ghost.colors.reshape(-1, 3)[0]) == node.GHOST_COLOUR


def _part_mm(node, pose):
    """A mesh node's vertices in part coordinates (mm), through the node's own pose in the scene."""
    R = trimesh.transformations.quaternion_matrix(node.wxyz)[:3, :3]
    machine = (np.asarray(node.vertices, float) @ R.T + np.asarray(node.position, float)) / SCALE
    return (machine - pose[:3, 3]) @ pose[:3, :3]


def test_the_picked_face_is_highlighted_replaced_by_the_next_pick_and_removed(app):
    """A click on the top face draws its whole CAD face (the block's top less the bore, boss, dome and cone) over
    the part as a translucent overlay lifted off the surface; a click into the bore replaces it by the bore's wall;
    Clear pick removes it, and so does the next part of a series (the pick itself is kept for the same CAD part)."""
    model = app.station.measurement
    pose = np.asarray(model.part.pose, float)
    R, t = pose[:3, :3], pose[:3, 3]
    with ui_support.viser_tab(app) as (_ws, capp):
        nodes = capp.client.scene._handle_from_node_name
        assert capp.pick(R @ [20.0, 60.0, 90.0] + t, R @ [0.0, 0.0, -1.0]) is not None
        top = capp.ctx.pick_drawing.face
        assert top is not None and nodes.get("/pick/face") is top and "/pick/point" in nodes
        assert top.opacity == HIGHLIGHT_OPACITY and top.color != (96, 128, 170)  # translucent, not the part's colour
        local = _part_mm(top, pose)
        assert np.allclose(local[:, 2], 40.0 + OFFSET_MM, atol=1e-4)  # on the top face, just above it
        lo, hi = local.min(axis=0), local.max(axis=0)
        assert np.allclose(lo[:2], [0.0, 0.0], atol=OFFSET_MM + 1e-3) and np.allclose(hi[:2], [120, 80], atol=0.2)
        area = trimesh.Trimesh(local, np.asarray(top.faces), process=False).area
        holes = np.pi * (15.0**2 + 10.0**2 + (10.0**2 - 1.0**2) + 12.0**2)  # bore, boss, dome's rim, cone's foot
        assert area == pytest.approx(120 * 80 - holes, rel=0.002)
        # the bore's wall, from its axis: the top face's overlay goes
        assert capp.pick(R @ [30.0, 40.0, 20.0] + t, R @ [1.0, 0.0, 0.0]) is not None
        bore = capp.ctx.pick_drawing.face
        assert bore is not top and nodes.get("/pick/face") is bore
        wall = _part_mm(bore, pose)
        radius = np.linalg.norm(wall[:, :2] - [30.0, 40.0], axis=1)
        assert np.allclose(radius, 15.0 - OFFSET_MM, atol=1e-3)  # lifted into the hole, off the material
        assert wall[:, 2].min() < 0.5 and wall[:, 2].max() > 39.5  # the whole through bore
        capp.clear_pick()
        assert capp.ctx.picked is None and "/pick/face" not in nodes and "/pick/point" not in nodes
        # the next part of a series: the drawing goes, the pick (same CAD faces) stays for its plan
        assert capp.pick(R @ [20.0, 60.0, 90.0] + t, R @ [0.0, 0.0, -1.0]) is not None
        assert capp.take_control()
        capp.ctx.commands.invoke(capp.ctx.who(), "new_part", name="next")
        capp.refresh()
        assert "/pick/face" not in nodes and capp.ctx.pick_drawing.face is None and capp.ctx.picked is not None
        capp.release_control()
