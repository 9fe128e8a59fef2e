"""The prompted hand alignment: element by element, where to touch, how many hits, the fit, then the alignment.

An operator aligns a part by hand the way commercial CMM software prompts it: choose the kind, then for each
element the page marks where to touch on the part, counts the hits as they come (by jog, by the pendant, or a
programmed hit at the marker), fits the element when it has its hits and shows it before the next one; a hit
can be taken again. The last element builds the alignment, which is shown and then applied.

Kinds (:data:`KINDS`):

- ``plane-line-point``: 3 hits on the top face (primary plane), 2 on the front face (secondary line), 1 on the
  left face (tertiary point): 6 hits. The line and the point need no CAD nominal: the CAD face they were taken
  on gives it (:func:`cmm.measurement.alignment.align_features`).
- ``3-2-1 planes``: three planes (4, 3, 3 hits) on the top, front and left faces.
- ``plane-circle-circle``: the top face, then two bores or bosses whose axes stand on it (4 hits each): the line
  from the first centre to the second is X, the first centre the origin.
- ``best fit``: 9 hits spread over the part, fitted to the CAD mesh.

Everything the wizard changes goes through the command API (``invoke(verb, **params)`` as the front end's
client: ``probe``, ``delete_hit``, ``measure_feature``, ``align``), so the access policy is the front end's;
hits reach it through the measurement model's listeners (:meth:`AlignWizard.hit_taken`). No GUI here: the
viser Align tab (:mod:`cmm.ui.panel_align`) shows :meth:`AlignWizard.text` and :meth:`AlignWizard.markers`.
"""

from __future__ import annotations

import queue
import threading
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from ..metrology.align import AlignmentError


@dataclass(frozen=True)
class Element:
    name: str  # "primary plane"
    kind: str  # plane | line | point | circle | hits (best fit)
    hits: int  # how many hits the wizard asks for
    face: tuple[float, float, float] | None = None  # the CAD face to touch: its outward normal (part coordinates)
    circle: int = 0  # plane-circle-circle: the first (1) or second (2) bore / boss standing on the primary


KINDS: dict[str, tuple[Element, ...]] = {
    "plane-line-point": (Element("primary plane", "plane", 3, (0, 0, 1)),
                         Element("secondary line", "line", 2, (0, -1, 0)),
                         Element("tertiary point", "point", 1, (-1, 0, 0))),
    "3-2-1 planes": (Element("primary plane", "plane", 4, (0, 0, 1)),
                     Element("secondary plane", "plane", 3, (0, -1, 0)),
                     Element("tertiary plane", "plane", 3, (-1, 0, 0))),
    "plane-circle-circle": (Element("primary plane", "plane", 3, (0, 0, 1)),
                            Element("first circle", "circle", 4, circle=1),
                            Element("second circle", "circle", 4, circle=2)),
    "best fit": (Element("hits on the part", "hits", 9),),
}
EDGE_MARGIN = 6.0  # mm: a marker keeps this far from the edges of its face (the tip's radius and then some)


@dataclass
class Step:
    element: Element
    hit_ids: list[int] = field(default_factory=list)
    feature: Any = None  # the fitted feature (or None)
    targets: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)  # (point, outward normal), part

    @property
    def complete(self) -> bool:
        return len(self.hit_ids) >= self.element.hits


class WizardError(ValueError):
    """What the wizard refuses, in an operator's words."""


# --- where to touch ------------------------------------------------------------------------------------------

def _face_candidates(mesh: Any, normal: np.ndarray, margin: float = EDGE_MARGIN, n: int = 600
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Points on the largest flat face whose outward normal is ``normal`` (part coordinates), at least ``margin``
    from its edges (inner ones too: holes, bosses), and the face's normal."""
    normals = np.asarray(mesh.facets_normal)
    areas = np.asarray(mesh.facets_area)
    ok = np.flatnonzero(normals @ normal > 0.999)
    if len(ok) == 0:
        raise WizardError(f"the part has no flat face facing ({normal[0]:g}, {normal[1]:g}, {normal[2]:g})")
    best = int(ok[np.argmax(areas[ok])])
    faces = mesh.facets[best]
    tri = mesh.triangles[faces]
    w = mesh.area_faces[faces] / mesh.area_faces[faces].sum()
    rng = np.random.default_rng(1)  # the same markers every time
    pick = rng.choice(len(faces), size=n, p=w)
    r = rng.random((n, 2))
    flip = r.sum(axis=1) > 1
    r[flip] = 1 - r[flip]
    pts = tri[pick, 0] + r[:, :1] * (tri[pick, 1] - tri[pick, 0]) + r[:, 1:] * (tri[pick, 2] - tri[pick, 0])
    edges = mesh.vertices[mesh.facets_boundary[best]]  # (m, 2, 3)
    a, b = edges[:, 0], edges[:, 1]
    ab = b - a
    t = np.clip(np.einsum("pmk,mk->pm", pts[:, None, :] - a[None], ab) / np.maximum((ab * ab).sum(1), 1e-12),
                0, 1)
    d = np.linalg.norm(pts[:, None, :] - (a[None] + t[..., None] * ab[None]), axis=2).min(axis=1)
    inside = pts[d >= margin]
    if len(inside) == 0:
        raise WizardError("the face is too narrow to touch away from its edges")
    return inside, np.asarray(normals[best], float)


def _spread(points: np.ndarray, n: int) -> np.ndarray:
    """``n`` of the points far apart (farthest-point sampling from the one nearest the middle)."""
    chosen = [int(np.argmin(np.linalg.norm(points - points.mean(axis=0), axis=1)))]
    if n > 1:  # start from an extreme instead: the spread is wider
        chosen = [int(np.argmax(np.linalg.norm(points - points[chosen[0]], axis=1)))]
    d = np.linalg.norm(points - points[chosen[0]], axis=1)
    while len(chosen) < n:
        nxt = int(np.argmax(d))
        chosen.append(nxt)
        d = np.minimum(d, np.linalg.norm(points - points[nxt], axis=1))
    return points[chosen]


def face_targets(mesh: Any, element: Element, primary: np.ndarray | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Where to touch for a plane, line or point element (part coordinates): (surface point, outward normal)."""
    pts, normal = _face_candidates(mesh, np.asarray(element.face, float))
    if element.kind == "point":
        chosen = pts[[int(np.argmin(np.linalg.norm(pts - pts.mean(axis=0), axis=1)))]]
    elif element.kind == "line":  # two hits at one height, far apart along the face
        up = np.asarray((0, 0, 1) if primary is None else primary, float)
        along = np.cross(up, normal)
        h = pts @ up
        band = pts[np.abs(h - np.median(h)) <= max(1.0, 0.1 * np.ptp(h))]
        s = band @ along
        chosen = band[[int(np.argmin(s)), int(np.argmax(s))]]
    else:
        chosen = _spread(pts, element.hits)
    return [(p, normal) for p in chosen]


def circle_targets(part: Any, element: Element, n: int) -> tuple[str, Any, list[tuple[np.ndarray, np.ndarray]]]:
    """(name, nominal cylinder in part coordinates, targets) of the plane-circle-circle's first or second bore or
    boss: the part's nominal cylinders whose axes stand on the top face, by name."""
    cyls = sorted((name, f) for name, f in (part.nominal_features or {}).items()
                  if f.kind == "cylinder" and abs(np.asarray(f.params["direction"], float)[2]) > 0.999)
    if len(cyls) < 2:
        raise WizardError("plane-circle-circle needs two bores or bosses standing on the top face of the part")
    name, cyl = cyls[element.circle - 1]
    p = np.asarray(cyl.params["point"], float)
    axis = np.asarray(cyl.params["direction"], float)
    axis = axis if axis[2] > 0 else -axis
    r = float(cyl.params["radius"])
    length = float(cyl.params.get("length", 10.0))
    base = p if np.asarray(cyl.params["direction"], float)[2] > 0 else p - length * axis
    centre = base + 0.5 * length * axis
    bore = bool(cyl.params.get("bore", False))
    out = []
    for a in np.radians(45.0 + 360.0 / n * np.arange(n)):
        radial = np.array([np.cos(a), np.sin(a), 0.0])
        out.append((centre + r * radial, -radial if bore else radial))
    return name, cyl, out


def best_fit_targets(mesh: Any, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Hits for a best fit spread over the top, front and left faces (three each for nine)."""
    faces = [(0, 0, 1), (0, -1, 0), (-1, 0, 0)]
    out: list[tuple[np.ndarray, np.ndarray]] = []
    for i, f in enumerate(faces):
        k = n // 3 + (1 if i < n % 3 else 0)
        pts, normal = _face_candidates(mesh, np.asarray(f, float))
        out += [(p, normal) for p in _spread(pts, k)]
    return out


# --- the wizard ----------------------------------------------------------------------------------------------

class AlignWizard:
    """One prompted alignment of ``kind`` on the model's part. ``invoke(verb, **params)`` sends a verb of the
    command API as the front end's client. Hits recorded while the wizard is active (:meth:`hit_taken`, which
    :meth:`listen` subscribes to the model) count for the element in hand; the element is fitted when it has its
    hits (``measure_feature``); after the last one :attr:`result` holds the alignment computed (not applied yet);
    :meth:`apply` sends the ``align`` verb."""

    def __init__(self, model: Any, invoke: Callable[..., Any], kind: str = "plane-line-point",
                 on_change: Callable[["AlignWizard"], None] | None = None,
                 elements: tuple[Element, ...] | None = None) -> None:
        if elements is None and kind not in KINDS:
            raise WizardError(f"the alignment kind must be one of {', '.join(KINDS)}, not {kind!r}")
        if model.part is None:
            raise WizardError("load a part before aligning it")
        self.model, self.invoke, self.kind = model, invoke, kind
        self.on_change = on_change
        self.lock = threading.RLock()
        self.elements = KINDS[kind] if elements is None else tuple(elements)
        self.fits = elements is None  # a routine's manual alignment: the routine fits and aligns, the wizard prompts
        self.steps = [Step(e) for e in self.elements]
        self.index = 0
        self.active = True
        self.result: Any = None  # the AlignmentResult computed after the last element
        self.applied = False
        self.message = ""  # the last fit or refusal, in words
        self.circle_nominals: dict[int, tuple[str, Any]] = {}
        self._seen: set[int] = set()  # every hit counted once, by whichever path told of it first
        self._queue: queue.Queue[int | None] = queue.Queue()
        self._worker: threading.Thread | None = None
        self._plan_targets()

    def _plan_targets(self) -> None:
        mesh = self.model.part.mesh
        for i, s in enumerate(self.steps):
            e = s.element
            if e.kind == "hits":
                s.targets = best_fit_targets(mesh, e.hits)
            elif e.kind == "circle":
                name, cyl, s.targets = circle_targets(self.model.part, e, e.hits)
                self.circle_nominals[i] = (name, cyl)
            else:
                s.targets = face_targets(mesh, e, np.asarray(self.elements[0].face, float))

    # --- what the page shows ------------------------------------------------------------------------------

    @property
    def step(self) -> Step | None:
        return self.steps[self.index] if self.index < len(self.steps) else None

    @property
    def done(self) -> bool:
        return self.index >= len(self.steps)

    def prompt(self) -> str:
        """What to do now, one sentence."""
        s = self.step
        if s is None:
            if not self.fits:
                return "Every hit taken: the routine aligns the part and measures on."
            if self.applied:
                return "Alignment applied."
            return "Alignment computed: check it, then Apply (or take an element again)."
        e = s.element
        where = self._where(self.index)
        return (f"Step {self.index + 1} of {len(self.steps)}: touch {where} ({e.name}): hit "
                f"{min(len(s.hit_ids) + 1, e.hits)} of {e.hits}")

    def _where(self, i: int) -> str:
        e = self.steps[i].element
        if e.kind == "circle":
            return f"the {self.circle_nominals[i][0]} at the markers"
        if e.kind == "hits":
            return "the part at the markers"
        face = {(0, 0, 1): "top", (0, -1, 0): "front", (-1, 0, 0): "left"}.get(
            tuple(float(round(v, 6)) for v in e.face or ()), "marked")
        if not self.fits:  # a routine's datum: its name
            return f"{e.name.split(' (')[0]} at the marker{'s' if e.hits > 1 else ''}"
        return f"the {face} face at the marker{'s' if e.hits > 1 else ''}"

    def markers(self) -> list[tuple[np.ndarray, np.ndarray, bool]]:
        """The current element's markers in machine coordinates: (point, outward normal, already hit)."""
        s = self.step
        if s is None:
            return []
        pose = np.asarray(self.model.part.pose, float)
        return [(pose[:3, :3] @ p + pose[:3, 3], pose[:3, :3] @ n, k < len(s.hit_ids))
                for k, (p, n) in enumerate(s.targets)]

    def text(self) -> str:
        """Markdown: every element with its hit count and fit, the prompt, the result."""
        lines = [f"**{self.kind}** alignment"]
        for i, s in enumerate(self.steps):
            mark = "→" if i == self.index else ("✓" if s.complete else "·")
            fit = ""
            if s.feature is not None and s.element.kind != "hits":
                fit = ": " + describe(s.feature)
            lines.append(f"{mark} {s.element.name}: {len(s.hit_ids)} of {s.element.hits} hits{fit}")
        lines.append(f"*{self.prompt()}*")
        if self.message:
            lines.append(self.message)
        if self.result is not None:
            part = self.model.part
            lines.append(self.result.text(None if part is None or self.applied else part.pose))
        return "\n\n".join(lines)

    # --- hits ---------------------------------------------------------------------------------------------

    def listen(self) -> None:
        """Count the model's new hits for the element in hand (until :meth:`close`). The model tells of a hit on
        the control core's dispatcher thread: the wizard only queues it there, and counts and fits it on a thread
        of its own (a fit never holds up the machine)."""
        if self._worker is None:
            self._worker = threading.Thread(target=self._drain, name="align-wizard", daemon=True)
            self._worker.start()
            self._unsubscribe = self.model.subscribe(self._event)

    def _event(self, kind: str, info: Any) -> None:
        if kind == "hit" and self.active and isinstance(info, tuple):
            self._queue.put(int(info[0]))

    def _drain(self) -> None:
        while True:
            hid = self._queue.get()
            try:
                if hid is None:
                    return
                self.hit_taken(hid)
            finally:
                self._queue.task_done()

    def settle(self) -> None:
        """Wait until the hits told so far are counted (and their element fitted)."""
        self._queue.join()

    def hit_taken(self, hid: int) -> None:
        """A hit was recorded: it counts for the element in hand; the element is fitted once it has its hits."""
        with self.lock:
            s = self.step
            if s is None or not self.active or hid in self._seen:
                return
            self._seen.add(hid)
            s.hit_ids.append(hid)
            if s.complete:
                self._fit(self.index)
        self._changed()

    def _fit(self, i: int) -> None:
        s = self.steps[i]
        e = s.element
        if e.kind == "hits" or not self.fits:
            s.feature = None
        else:
            params: dict[str, Any] = {"kind": e.kind, "hits": list(s.hit_ids), "name": f"ALN {e.name}"}
            if e.kind == "circle":
                from ..metrology.pick import NominalFeature

                _name, cyl = self.circle_nominals[i]
                params["nominal"] = NominalFeature(cyl.kind, dict(cyl.params)).transformed(self.model.part.pose)
            try:
                s.feature = self.invoke("measure_feature", **params)
            except Exception as exc:  # noqa: BLE001 - a fit that cannot be made is shown, the hits retaken
                s.feature = None
                self.message = f"{e.name} could not be fitted: {exc}. Take its hits again."
                return
            if s.feature is None:
                self.message = f"{e.name} could not be fitted. Take its hits again."
                return
            self.message = f"{e.name} fitted: {describe(s.feature)}"
        # on to the first element still without its fit (an element taken again: the later ones stand)
        self.index = next((k for k, t in enumerate(self.steps) if not t.complete or (
            self.fits and t.feature is None and t.element.kind != "hits")), len(self.steps))
        if self.done and self.fits:
            self._compute()

    def _compute(self) -> None:
        from . import alignment

        try:
            if self.kind == "best fit":
                self.result = alignment.best_fit_hits(self.model, self.steps[0].hit_ids)
            else:
                fids = [s.feature.id for s in self.steps]
                self.result = alignment.align_features(self.model, *fids)
            self.message = ""
        except (AlignmentError, ValueError) as exc:
            self.result = None
            self.message = f"The alignment cannot be computed: {exc}"

    def probe_marker(self) -> Any:
        """Take the next hit at the marker (a programmed hit, along the marker's normal into the face)."""
        s = self.step
        if s is None:
            raise WizardError("every element has its hits: apply the alignment or take an element again")
        p, n, _hit = self.markers()[len(s.hit_ids)]
        status = self.invoke("probe", target=[float(x) for x in p], approach=[float(-x) for x in n], frame="machine")
        hit = status.wait() if hasattr(status, "wait") else status
        if hit is not None:
            self.hit_taken(self.model.hit_id(hit))  # once: the listener's copy of it is not counted again
        return hit

    def retake(self, element: int | None = None) -> None:
        """Take the hits of an element again (default: the one in hand, or the last one): its hits are deleted
        (undo brings them back), its fit dropped, and the wizard goes back to it; the later elements stay."""
        with self.lock:
            i = self.index if element is None else int(element)
            if element is None and (self.done or not self.steps[i].hit_ids) and i > 0:
                i -= 1
            if not 0 <= i < len(self.steps):
                raise WizardError(f"there is no element {i + 1}")
            s = self.steps[i]
            for hid in s.hit_ids:
                if hid in self.model.hits:
                    self.invoke("delete_hit", hit=hid)
            if s.feature is not None and s.feature.id in self.model.features:
                self.invoke("delete_feature", feature=s.feature.id)
            s.hit_ids, s.feature = [], None
            self.result, self.applied, self.message = None, False, f"Take the hits of the {s.element.name} again."
            self.index = i
        self._changed()

    def retake_last_hit(self) -> None:
        """Delete the last hit of the element in hand (a touch that went wrong) and count it again."""
        with self.lock:
            s = self.step
            if s is None or not s.hit_ids:
                raise WizardError("no hit of this element to take again")
            self.invoke("delete_hit", hit=s.hit_ids.pop())
            self.message = "The last hit was deleted: take it again."
        self._changed()

    def apply(self) -> Any:
        """Adopt the alignment computed (the ``align`` verb: computed again from the same elements, journalled)."""
        if self.result is None:
            raise WizardError("the alignment is not computed yet: take every element's hits first")
        if self.kind == "best fit":
            done = self.invoke("align", hits=list(self.steps[0].hit_ids))
        else:
            ids = [s.feature.id for s in self.steps]
            done = self.invoke("align", primary=ids[0], secondary=ids[1], tertiary=ids[2])
        self.result, self.applied, self.active = done, True, False
        self._changed()
        return done

    def close(self) -> None:
        """Stop counting hits: the model's listener and the counting thread end."""
        self.active = False
        if self._worker is not None:
            self._unsubscribe()
            self._queue.put(None)

    def _changed(self) -> None:
        if self.on_change is not None:
            try:
                self.on_change(self)
            except Exception:  # noqa: BLE001 - a page that went away must not stop the counting
                pass


def routine_elements(routine: Any, datums: list[str]) -> tuple[Element, ...]:
    """A routine's manual 3-2-1 as the wizard's elements: 3 hits on the primary datum plane, 2 on the secondary, 1
    on the tertiary (:data:`cmm.measurement.routine.MANUAL_HITS`), each on the CAD face of its nominal plane."""
    out = []
    for what, kind, n, d in zip(("primary", "secondary", "tertiary"), ("plane", "line", "point"), (3, 2, 1), datums):
        nom = routine.feature(d).nominal
        if not nom or nom.get("kind") != "plane":
            raise WizardError(f"the manual alignment needs the nominal plane of {d}")
        normal = np.asarray(nom["normal"], float)
        out.append(Element(f"{d} ({what} datum)", kind, n, tuple(float(v) for v in normal / np.linalg.norm(normal))))
    return tuple(out)


def routine_manual_hits(run: Any, wizard_for: Callable[[list[str]], "AlignWizard"]) -> Callable[[str, int], list[int]]:
    """A routine run's ``manual_hits(prompt, n)`` that the wizard prompts: on the first datum it starts the wizard
    (``wizard_for(datums)``: the front end's, so its page shows the markers and the counts); each call waits until
    the element in hand has its ``n`` hits and returns them. The run's progress says what to touch meanwhile; a
    cancel of the run ends the wait."""
    state: dict[str, Any] = {}

    def hits(prompt: str, n: int) -> list[int]:
        step = run.routine.steps[next(i for i, s in enumerate(run.routine.steps) if s["kind"] == "align")]
        w = state.get("wizard")
        if w is None or w.done:
            w = state["wizard"] = wizard_for(list(step["datums"]))
        i = w.index
        runner = run.runner  # the part programs' runner: its progress and its cancel
        runner.tell(state="waiting", prompt=prompt)
        while True:
            w.settle() if w._worker is not None else None
            if w.index > i or w.done:
                runner.tell(state="running", prompt="")
                return list(w.steps[i].hit_ids[:n])
            if runner.cancelled:
                w.close()
                from .routine_run import RoutineCancelled

                raise RoutineCancelled("the routine was cancelled while waiting for manual hits")
            shown = f"{prompt}: {len(w.steps[i].hit_ids)} of {n} taken"
            if run.progress.prompt != shown:
                runner.tell(prompt=shown)
            runner.sleep(0.1)
    return hits


def describe(feature: Any) -> str:
    """A fitted element in a few words (machine coordinates): where it is and how well the hits fit."""
    g = feature.result.geometry()
    kind = feature.kind
    form = getattr(feature.result, "form_error", None)
    tail = "" if form is None or kind == "point" else f", form {form * 1000:.1f} µm"
    if kind == "plane":
        n = g["normal"]
        return f"normal ({n[0]:.5f}, {n[1]:.5f}, {n[2]:.5f}){tail}"
    if kind == "line":
        d = g["direction"]
        return f"direction ({d[0]:.5f}, {d[1]:.5f}, {d[2]:.5f}){tail}"
    if kind == "point":
        p = g["point"]
        return f"X {p[0]:.4f} Y {p[1]:.4f} Z {p[2]:.4f}"
    if kind in ("circle", "sphere"):
        c = g["center"]
        return f"centre X {c[0]:.4f} Y {c[1]:.4f} Z {c[2]:.4f}, D {2 * g['radius']:.4f}{tail}"
    return kind
