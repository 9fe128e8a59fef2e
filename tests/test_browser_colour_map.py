"""The deviation colour map in headless chromium: hits probed on the simulated part, a best-fit alignment, the
map turned on in the Colour map tab (the part mesh in the scene gets vertex colours in the scale's bands), the
legend with the band limits, new bands applied from the page, the map off again, and the report's map views.
Screenshots: test-artifacts/colour-map-*.png (and the report, HTML and PDF).
"""

from __future__ import annotations

import io

import numpy as np
import pytest

import browser_support as bs

_reason = bs.unavailable_reason()
pytestmark = [pytest.mark.browser, pytest.mark.timeout(600),
              pytest.mark.skipif(_reason is not None, reason=_reason or "")]

pytest.importorskip("viser")

import trimesh  # noqa: E402

from cmm.measurement import alignment  # noqa: E402
from cmm.metrology.colour_map import to_linear  # noqa: E402
from cmm.metrology.colour_scale import GREEN, GREY  # noqa: E402
from cmm.journal.writer import read_events  # noqa: E402
from cmm.journal.session import Session  # noqa: E402
from cmm.session.report import render  # noqa: E402
from cmm.ui.scene import SCALE  # noqa: E402

LAPTOP = (1280, 800)
# (point on the face, outward normal) in part coordinates: 3-2-1 hits on the top, front and left faces
HITS = [((10.0, 70.0, 40.0), (0, 0, 1)), ((50.0, 8.0, 40.0), (0, 0, 1)), ((110.0, 10.0, 40.0), (0, 0, 1)),
        ((20.0, 0.0, 30.0), (0, -1, 0)), ((100.0, 0.0, 25.0), (0, -1, 0)), ((0.0, 30.0, 20.0), (-1, 0, 0))]


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    yield from bs.sim_station(tmp_path_factory, "map")


@pytest.fixture(scope="module")
def app(station):
    yield from bs.station_app(station, pendant=False)


def glb_colours(handle) -> tuple[trimesh.Trimesh, np.ndarray]:
    """The mesh and RGB vertex colours the scene node sends to the browsers (its GLB)."""
    mesh = trimesh.load(io.BytesIO(handle.glb_data), file_type="glb", force="mesh")
    return mesh, np.asarray(mesh.visual.vertex_colors)[:, :3]


def test_colour_map_in_the_scene_legend_bands_and_report(app, station):
    pose = station.measurement.part.pose
    for p, n in HITS:  # probed along the nominal normal at the nominal set-up
        target = pose[:3, :3] @ np.array(p) + pose[:3, 3]
        station.measurement.probe(target, -(pose[:3, :3] @ np.array(n, float))).wait(60)
    assert len(station.measurement.hits) == len(HITS)
    alignment.apply(station.measurement, alignment.best_fit_hits(station.measurement, sorted(station.measurement.hits)))  # in part coordinates
    app.redraw()
    devs = station.measurement.hit_deviations()
    assert max(abs(d) for d in devs.values()) < 0.01  # aligned: a few um

    with bs.browser_context(viewport=LAPTOP) as context:
        page = context.new_page()
        log = bs.PageLog()
        log.attach(page)
        before = set(app.clients)
        page.goto(bs.app_url(app))
        capp = app.clients[bs.new_client(page, app, before)]
        bs.open_tab(page, "Measure", "Colour map")
        legend = page.locator(".cmm-legend")
        # the legend lists the band limits of the shared scale (default: +-20 um, warning from +-10 um)
        legend.get_by_text("within ±10 µm").filter(visible=True).first.wait_for()
        shown = legend.inner_text()
        for text in ("> +20 µm out of tolerance", "+10 .. +20 µm warning", "-20 .. -10 µm warning",
                     "< -20 µm out of tolerance", "beyond ±0.5 mm, unknown, or no hit within 15 mm"):
            assert text in shown, shown
        assert app.view.map is None and app.view._part_node.visible

        # --- the map on: the part is replaced by the vertex-coloured map (in every tab's scene)
        bs.tick_until(page, "Show the colour map", True, lambda: app.view._map_node is not None,
                      "the colour map in the scene")  # a tick on a panel that re-flowed is repeated
        assert not app.view._part_node.visible
        dmap = app.view.map
        mesh, stored = glb_colours(app.view._map_node)
        assert len(mesh.vertices) == len(dmap.mesh.vertices) and len(stored) == len(mesh.vertices)
        assert np.array_equal(stored, to_linear(dmap.vertex_colours))  # the map's colours (linear, as glTF wants)
        colours = {tuple(c) for c in dmap.vertex_colours.tolist()}
        assert colours == {GREY, GREEN}  # aligned: green around the hits, grey away from them
        # at each hit the surface has that hit's colour (the vertex nearest to it)
        local = (np.array([station.measurement.hits[h].point for h in sorted(station.measurement.hits)]) - station.measurement.part.pose[:3, 3]) \
            @ station.measurement.part.pose[:3, :3]
        nearest = np.linalg.norm(dmap.mesh.vertices[:, None, :] - local[None], axis=2).argmin(axis=0)
        assert {tuple(c) for c in dmap.vertex_colours[nearest].tolist()} == {GREEN}
        bs.shows(page, f"{len(HITS)} hits paint")  # "6 hits paint N % of the surface"
        covered = dmap.coverage
        # look at the part for the screenshot
        centre = (station.measurement.part.pose[:3, :3] @ np.array([60.0, 40.0, 20.0]) + station.measurement.part.pose[:3, 3]) * SCALE
        capp.client.camera.look_at = tuple(centre)
        capp.client.camera.position = tuple(centre + np.array([0.09, -0.16, 0.14]))
        page.wait_for_timeout(1000)
        bs.screenshot(page, "colour-map-on")

        # --- a new hit while the map is on: the map follows (drawn in the background, the DRO keeps its rate)
        target = station.measurement.part.pose[:3, :3] @ np.array([95.0, 70.0, 40.0]) + station.measurement.part.pose[:3, 3]
        station.measurement.probe(target, -station.measurement.part.pose[:3, 2]).wait(60)
        bs.wait_until(lambda: app.view.map is not None and app.view.map.hits_used == len(HITS) + 1, 30.0,
                      "the map with the new hit")
        bs.shows(page, f"{len(HITS) + 1} hits paint")
        covered = app.view.map.coverage

        # --- new bands and reach from the page: the legend and the map follow
        page.get_by_label("Tolerance ± (mm)", exact=True).fill("0.004")
        page.get_by_label("Reach (mm)", exact=True).fill("40")
        bs.press(page, "Apply bands")
        legend.get_by_text("within ±2 µm").filter(visible=True).first.wait_for()
        shown = legend.inner_text()
        assert "> +4 µm out of tolerance" in shown and "no hit within 40 mm" in shown, shown
        bs.wait_until(lambda: app.view.map is not None and app.view.map.scale.reach == 40.0, 30.0,
                      "the map with the new reach")
        wide = app.view.map
        assert wide.coverage > 2 * covered  # a longer reach paints more of the part
        # the map is computed before its node replaces the last one in the scene (drawn in the background): wait
        expected = to_linear(app.view.scale.colours(wide.vertex_deviations))
        bs.wait_until(lambda: app.view._map_node is not None
                      and glb_colours(app.view._map_node)[1].shape == expected.shape, 30.0, "the new map's node")
        _, stored = glb_colours(app.view._map_node)
        assert np.array_equal(stored, expected)
        assert np.array_equal(wide.vertex_colours, app.view.scale.colours(wide.vertex_deviations))

        # --- the report of this session draws its map views in the same bands
        session = Session.from_events(read_events(station.measurement.journal.path).events, "map")
        page_html = render(session, mesh=station.measurement.part.mesh, colour_scale=app.view.scale)
        assert page_html.count('class="map"') == 3 and "&gt; +4 µm out of tolerance" in page_html
        report = bs.ARTIFACTS / "colour-map-report.html"
        report.write_text(page_html, encoding="utf-8")
        rp = context.new_page()  # printed to PDF: the map images print with the page (print CSS)
        rp.goto(report.as_uri())
        views = rp.locator(".views")
        views.scroll_into_view_if_needed()
        assert views.locator("image.map").count() == 3
        bs.screenshot(rp, "colour-map-report-views", clip=views.bounding_box())
        pdf = rp.pdf(format="A4")
        (bs.ARTIFACTS / "colour-map-report.pdf").write_bytes(pdf)
        assert pdf.startswith(b"%PDF") and b"/Subtype /Image" in pdf
        rp.close()

        # --- off again: the plain part is back
        bs.tick_until(page, "Show the colour map", False, lambda: app.view._map_node is None, "the map removed")
        assert app.view._part_node.visible and not app.view.map_on
        assert log.page_errors == [], log.problems
