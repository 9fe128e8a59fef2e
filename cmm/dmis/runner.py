"""Run a DMIS program on the station: check it all, then run it as one job of the control core.

:func:`run_text` refuses a program with any problem (syntax, an unsupported statement, an unclosed block) before
anything moves, then holds the machine for the whole run (``controller.run_job``) and moves and probes through
the control core, so the access policy, STOP and the journal work as for every other front end.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .check import check
from .executor import DmisError, Executor, RunResult


class StationTarget:
    """The station as a DMIS target: straight moves, programmed hits with the program's cycle, its model."""

    def __init__(self, station: Any, client: Any = None, timeout: float = 120.0) -> None:
        self.station = station
        self.controller = station.controller
        self.model = station.measurement
        self.client = client
        self.timeout = timeout

    def position(self) -> np.ndarray:
        return np.asarray(self.station.machine.position, float)

    def move(self, target: np.ndarray, speed: float | None) -> None:
        """A DMIS GOTO: a straight line, which the control core's rails take only when it is proven free of the
        part (else they refuse it in words, and the program stops on that line)."""
        self.controller.move(self.client, target, frame="machine", path="straight", speed=speed).wait(self.timeout)

    def probe(self, point: np.ndarray, approach: np.ndarray, *, speed: float | None, approach_distance: float,
              search_distance: float, retract_distance: float, rapid_speed: float | None) -> int:
        """A PTMEAS: straight to the pre-hit point (proven free of the part), then the probing move."""
        hit = self.controller.probe(self.client, point, approach, frame="machine", path="straight",
                                    speed=speed or self.probing_speed, approach_distance=approach_distance,
                                    search_distance=search_distance, retract_distance=retract_distance,
                                    rapid_speed=rapid_speed).wait(self.timeout)
        return int(self.model.hit_id(hit))

    @property
    def tip_radius(self) -> float:
        return float(self.station.prober.settings.tip_radius)

    @property
    def probing_speed(self) -> float:
        return float(self.station.calibration.qualified_probing_speed)

    @property
    def positioning_speed(self) -> float:
        return float(self.station.config.speeds.positioning)

    @property
    def probe_distances(self) -> tuple[float, float, float]:
        p = self.station.config.probe
        return float(p.approach_distance), float(p.search_distance), float(p.retract_distance)


def load_text(path: str | Path) -> str:
    p = Path(path)
    try:
        return p.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise DmisError(f"cannot read the DMIS program {p}: {exc.strerror or exc}") from None


def run_text(text: str, station: Any, *, name: str = "program", client: Any = None) -> RunResult:
    """Check ``text`` and run it on ``station`` (connected, homed): the run's actuals, tolerances and output."""
    stmts, problems = check(text)
    if problems:
        raise DmisError(problems[0])
    executor = Executor(stmts, StationTarget(station, client), name=name)
    return station.controller.run_job(client, f"DMIS program {name!r}", executor.run, timeout=None)
