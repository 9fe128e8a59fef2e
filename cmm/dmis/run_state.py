"""What a DMIS run is made of: its error, its result, the target it runs on, and a statement as text.

Shared by :class:`cmm.dmis.executor.Executor` and the mixins that carry out its statements
(:mod:`cmm.dmis.alignments`, :mod:`cmm.dmis.reporting`, :mod:`cmm.dmis.vendor`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from .features import Actual
from .parser import Label, Param, Statement, Text, Word
from .tolerances import Evaluation


class DmisError(RuntimeError):
    """A DMIS program stopped: "line N: what happened". ``result``: what the run had done by then (its actuals
    and the output up to that line, ending in a ``$$`` comment that says why), or None when nothing ran."""

    result: "RunResult | None" = None


class Target(Protocol):
    model: Any  # the measurement model, read only: hits, features, datums (fits go through ``fit``, notes ``note``)

    def position(self) -> np.ndarray: ...
    def move(self, target: np.ndarray, speed: float | None) -> None: ...
    def probe(self, point: np.ndarray, approach: np.ndarray, *, speed: float | None, approach_distance: float,
              search_distance: float, retract_distance: float, rapid_speed: float | None) -> int: ...
    def manual_hits(self, prompt: str, n: int, guides: list[tuple[np.ndarray, np.ndarray]]) -> list[int]: ...
    def align(self, measured: np.ndarray, nominal: np.ndarray, points: np.ndarray, name: str) -> str: ...
    def fit(self, kind: str, hit_ids: list[int], name: str, nominal: Any) -> Any: ...
    def note(self, text: str) -> None: ...
    def set_tolerance(self, feature_id: int, tolerance: dict[str, float]) -> None: ...
    def set_nominal(self, feature_id: int, nominal: Any) -> None: ...
    def define_datum(self, label: str, feature_id: int) -> None: ...
    def define_position(self, feature_id: int, tolerance: float, datums: list[str], *, material: str, name: str,
                        datum_modifiers: dict[str, str] | None) -> None: ...
    def probes(self) -> list[dict[str, Any]] | None: ...
    def select_probe(self, name: str) -> str: ...
    def tell(self, text: str) -> None: ...
    def hold(self, done: Any) -> None: ...
    def ask(self, prompt: str, *, answer: bool) -> str: ...
    def run_end(self, series: str, *, values: Any = None, event: Any = None, stopped: Any = None) -> None: ...
    @property
    def tip_radius(self) -> float: ...
    @property
    def nominal_tip_diameter(self) -> float: ...
    @property
    def probing_speed(self) -> float: ...
    @property
    def positioning_speed(self) -> float: ...
    @property
    def probe_distances(self) -> tuple[float, float, float]: ...


@dataclass
class RunResult:
    actuals: dict[str, Actual] = field(default_factory=dict)
    evaluations: list[Evaluation] = field(default_factory=list)
    outputs: dict[str | None, str] = field(default_factory=dict)  # device file (None: the default output) -> text
    log: list[str] = field(default_factory=list)
    hits: int = 0
    frames: dict[str, np.ndarray] = field(default_factory=dict)  # D(label) -> program -> machine, as defined
    # what re-evaluating the session replays the program with (cmm.dmis.replay): the hits in the order taken, the
    # operator's TEXT/QUERY answers, whether each alignment moved the part
    hit_ids: list[int] = field(default_factory=list)
    answers: list[str] = field(default_factory=list)
    aligned: list[bool] = field(default_factory=list)
    recalled: dict[str, Any] = field(default_factory=dict)  # RECALL of an item an earlier program saved: key -> it


def replay_data(text: str, result: RunResult, skipped: dict[str, str]) -> dict[str, Any] | None:
    """What re-evaluating the run's session needs to run the program again on its refitted hits
    (:mod:`cmm.dmis.replay`), as JSON; None without the program's text."""
    if not text:
        return None
    if skipped:  # a skip is the operator's, at a moment the replay cannot tell
        return {"refused": "the operator skipped " + ", ".join(f"F({k})" for k in skipped) + " during the run"}
    from .saved import encode

    return {"text": text, "hit_ids": list(result.hit_ids), "answers": list(result.answers),
            "aligned": list(result.aligned), "recalled": {k: encode(k, v) for k, v in result.recalled.items()}}


def _text(p: Param) -> str:
    if isinstance(p, Word):
        return p.text
    if isinstance(p, Text):
        return f"'{p.text}'"
    if isinstance(p, Label):
        return str(p)
    toks = p.tokens
    return "".join(t.text if t.kind != "str" else f"'{t.value}'" for t in toks)


def statement_text(s: Statement) -> str:
    head = f"{s.label} = " if s.label else (f"{s.variable} = " if s.variable else "")
    return head + s.major + ("/" + ", ".join(_text(p) for p in s.params) if s.params else "")


def blocks(stmts: list[Statement]) -> dict[int, int]:
    """Statement index -> where its block goes on: MEAS <-> ENDMES, DO <-> ENDDO, MACRO -> ENDMAC, IF -> ELSE (or
    ENDIF), ELSE -> ENDIF. The check has matched them already."""
    pairs: dict[int, int] = {}
    stack: list[int] = []
    for k, s in enumerate(stmts):
        if s.major in ("MEAS", "IF", "DO", "MACRO"):
            stack.append(k)
        elif s.major == "ELSE":
            pairs[stack[-1]] = k
            stack[-1] = k
        elif s.major in ("ENDMES", "ENDIF", "ENDDO", "ENDMAC"):
            start = stack.pop()
            pairs[start] = k
            pairs[k] = start
    return pairs

