"""The statements of the DMIS programs vendors export (PC-DMIS, CALYPSO ...), for :class:`cmm.dmis.executor.Executor`.

- ``SNSMNT/XVEC, i, j, k, ZVEC, i, j, k, MNTOFF, x, y, z``: the probe head's axes; the SNSDEF directions after it
  are given in them (the station's probe must still point down);
- ``SAVE/DA(x)`` and ``RECALL/DA(x)`` (``D(x)`` too): a coordinate system kept and put back; ``SAVE/DAT(A)``,
  ``SAVE/FA(x)``, ``SAVE/SA(x)`` and their RECALL: a datum, an actual, a sensor kept; on the station they are kept
  in its records for later programs too (:mod:`cmm.dmis.saved`): a RECALL of what this run did not save finds
  the last SAVE of an earlier program;
- ``WKPLAN/XYPLAN | YZPLAN | ZXPLAN``: the working plane a 2D position of a point is taken in;
- ``TEXT/OUTFIL, 'text'``: a line of the output file; ``TEXT/OPER, 'text'``: told to the operator (the page's
  program status, the terminal, the journal); ``TEXT/MAN, 'text'`` waits for the operator to confirm it and
  ``TEXT/QUERY, (name), n, ALPHA, L, 'text'`` for their answer, which the variable ``name`` then holds;
- ``DID(x) = DEVICE/STOR, 'path'`` with ``OPEN/DID(x), FDATA, DMIS, OUTPUT`` (or ``DIRECT, OUTPUT``): a file
  that receives the output while it is open (with the FILNAM and UNITS before it, closed by ENDFIL), written in
  the run's output folder under the path's last name whatever folder the program names (never outside it).
"""

from __future__ import annotations

from typing import Any

from .parser import Expr, Label, Statement, Text, Word
from .rules import SAVED, device_file, mount_matrix, open_problem


class VendorStatements:
    """Mixin of :class:`cmm.dmis.executor.Executor` (its state: frames, datums, actuals, sensors, output)."""

    mount: list | None
    work_plane: str
    saved: dict[str, Any]
    device_lines: dict[str, list[str]]

    def _vendor_init(self) -> None:
        self.mount = None
        self.work_plane = "XYPLAN"
        self.saved = {}
        self.device_lines = {}  # DID name -> its lines so far (opened for output at least once)

    # --- output ------------------------------------------------------------------------------

    def emit(self, line: str) -> None:
        self.output.append(line)  # type: ignore[attr-defined]
        for name in self.open_devices:  # type: ignore[attr-defined]
            self.device_lines[name].append(line)

    def _finish(self) -> None:
        self.emit("ENDFIL")
        result = self.result  # type: ignore[attr-defined]
        if not self.device_lines:  # no device opened: the run's output file
            result.outputs[None] = "\n".join(self.output) + "\n"  # type: ignore[attr-defined]
            return
        for name, lines in self.device_lines.items():
            if not lines or lines[-1] != "ENDFIL":
                lines = lines + ["ENDFIL"]
            path = device_file(self.devices[name] or "")  # type: ignore[attr-defined]
            if path is not None:
                result.outputs[path] = "\n".join(lines) + "\n"

    def do_device(self, s: Statement) -> None:
        texts = [p.text for p in s.params if isinstance(p, Text)]
        path = texts[0] if s.minor == "STOR" and texts else None
        if path is not None and device_file(path) is None:
            raise self.fail(s, f"DEVICE/STOR, '{path}' names no file")  # type: ignore[attr-defined]
        if path is not None and device_file(path) != path:
            self.log(f"line {s.line}: DID({s.label.name}) is written as {device_file(path)} in the run's "  # type: ignore
                     f"output folder (the program names {path})")
        self.devices[s.label.name] = path  # type: ignore[attr-defined, union-attr]

    def do_open(self, s: Statement) -> None:
        name = self.labels(s)[0].name  # type: ignore[attr-defined]
        if name not in self.devices:  # type: ignore[attr-defined]
            raise self.fail(s, f"DID({name}) is not defined (DID({name}) = DEVICE/STOR, 'file')")  # type: ignore
        words = self.words(s)  # type: ignore[attr-defined]
        problem = open_problem(words)
        if problem:
            raise self.fail(s, problem)  # type: ignore[attr-defined]
        if self.devices[name] is None:  # type: ignore[attr-defined]
            raise self.fail(s, f"DID({name}) is no file: OPEN takes a DEVICE/STOR")  # type: ignore[attr-defined]
        if name not in self.device_lines or "APPEND" not in words:
            # a new file starts with the program's name and units, as the run's output file does
            self.device_lines[name] = [line for line in self.output  # type: ignore[attr-defined]
                                       if line.startswith(("FILNAM", "UNITS"))]
        if name not in self.open_devices:  # type: ignore[attr-defined]
            self.open_devices.append(name)  # type: ignore[attr-defined]

    def do_close(self, s: Statement) -> None:
        name = self.labels(s)[0].name  # type: ignore[attr-defined]
        if name in self.open_devices:  # type: ignore[attr-defined]
            self.open_devices.remove(name)  # type: ignore[attr-defined]
            self.device_lines[name].append("ENDFIL")

    # --- operator texts ---------------------------------------------------------------------------

    def do_text(self, s: Statement) -> None:
        text = " ".join(p.text for p in s.params if isinstance(p, Text))
        kind = s.minor
        if kind == "OUTFIL":
            self.emit(f"TEXT/OUTFIL, '{text}'")
            return
        if kind == "OPER":
            self.log(f"line {s.line}: {text}")  # type: ignore[attr-defined]
            self.target.tell(text)  # type: ignore[attr-defined]
            return
        if kind == "MAN":
            self.target.ask(f"line {s.line}: {text}", answer=False)  # type: ignore[attr-defined]
            self.log(f"line {s.line}: {text} (confirmed by the operator)")  # type: ignore[attr-defined]
            return
        name = self._query_name(s)
        answer = self.target.ask(f"line {s.line}: {text}", answer=True)  # type: ignore[attr-defined]
        self.result.answers.append(str(answer))  # type: ignore[attr-defined]
        self.variables[name] = answer  # type: ignore[attr-defined]
        self.emit(f"TEXT/OUTFIL, '{text} {answer}'")
        self.target.note(f"DMIS line {s.line}: {text} {answer}")  # type: ignore[attr-defined]

    def _query_name(self, s: Statement) -> str:
        """The name a TEXT/QUERY's answer goes to: ``(name)`` or ``name`` after QUERY."""
        for p in s.params[1:]:
            if isinstance(p, Word):
                return p.text
            if isinstance(p, Label):
                return p.name
            if isinstance(p, Expr):
                words = [t.text for t in p.tokens if t.kind == "word"]
                if words:
                    return words[0]
        return "QUERY"

    # --- head, working plane, saved items ------------------------------------------------------------

    def do_snsmnt(self, s: Statement) -> None:
        matrix, problem = mount_matrix(self.numbers(s), self.words(s))  # type: ignore[attr-defined]
        if problem:
            raise self.fail(s, problem)  # type: ignore[attr-defined]
        self.mount = matrix

    def do_wkplan(self, s: Statement) -> None:
        self.work_plane = str(s.minor)

    def _saved_key(self, label: Label) -> str:
        return f"{'DA' if label.type == 'D' else label.type}({label.name})"

    def do_save(self, s: Statement) -> None:
        label = self.labels(s)[0]  # type: ignore[attr-defined]
        key, name = self._saved_key(label), label.name
        if label.type in ("D", "DA"):
            if name not in self.frames:  # type: ignore[attr-defined]
                raise self.fail(s, f"D({name}) has not been defined")  # type: ignore[attr-defined]
            self.saved[key] = (self.frames[name].copy(), self.design_frames[name].copy())  # type: ignore
        elif label.type == "DAT":
            if name not in self.datums:  # type: ignore[attr-defined]
                raise self.fail(s, f"DAT({name}) is not defined (DATDEF/FA(name), DAT({name}))")  # type: ignore
            self.saved[key] = self.datums[name]  # type: ignore[attr-defined]
        elif label.type == "FA":
            self.saved[key] = self.actual(s, label)  # type: ignore[attr-defined]
        else:
            if name not in self.sensors:  # type: ignore[attr-defined]
                raise self.fail(s, f"S({name}) is not defined (S({name}) = SNSDEF/PROBE, ...)")  # type: ignore
            self.saved[key] = dict(self.sensors[name])  # type: ignore[attr-defined]
        self.emit(f"SAVE/{key}")
        store = self._store()
        if store is not None:  # kept for the station's next programs too (cmm.dmis.saved)
            try:
                store.keep(key, self.saved[key], self.name)  # type: ignore[attr-defined]
            except OSError as exc:
                self.log(f"line {s.line}: {key} is saved for this run only: {exc}")  # type: ignore[attr-defined]

    def _store(self) -> Any:
        """The station's saved items (None: a target without records keeps SAVE within the run)."""
        get = getattr(self.target, "saved_items", None)  # type: ignore[attr-defined]
        return None if get is None else get()

    def _recalled(self, s: Statement, key: str) -> Any:
        """An item another program saved on this station (None: none was)."""
        store = self._store()
        if store is None:
            return None
        try:
            got = store.recall(key)
        except OSError as exc:
            raise self.fail(s, str(exc))  # type: ignore[attr-defined]
        if got is None:
            return None
        self.log(f"line {s.line}: {key} as saved by {got[1]}")  # type: ignore[attr-defined]
        self.saved[key] = got[0]
        self.result.recalled[key] = got[0]  # type: ignore[attr-defined]
        return got[0]

    def do_recall(self, s: Statement) -> None:
        label = self.labels(s)[0]  # type: ignore[attr-defined]
        key, name = self._saved_key(label), label.name
        kept = self.saved.get(key)
        if kept is None and (label.type not in ("D", "DA") or name not in self.frames):  # type: ignore[attr-defined]
            kept = self._recalled(s, key)  # saved by an earlier program on this station
        if label.type in ("D", "DA"):
            if kept is None:
                if name not in self.frames:  # type: ignore[attr-defined]
                    raise self.fail(s, f"D({name}) has not been defined or saved (by this program or an earlier "  # type: ignore
                                       "one on this station)")
                kept = (self.frames[name], self.design_frames[name])  # type: ignore[attr-defined]
            self.frame, self.design_frame = kept[0].copy(), kept[1].copy()
            self.emit(f"RECALL/D({name})" if label.type == "D" else f"RECALL/DA({name})")
            return
        if kept is None:
            raise self.fail(s, f"{label} has not been saved (SAVE/{label}, by this program or an earlier one on "  # type: ignore
                               "this station)")
        if label.type == "DAT":
            self.datums[name] = kept  # type: ignore[attr-defined]
        elif label.type == "FA":
            self.result.actuals[name] = kept  # type: ignore[attr-defined]
        else:
            self.sensors[name] = dict(kept)  # type: ignore[attr-defined]


__all__ = ["SAVED", "VendorStatements"]
