"""A measurement model without a station: a Machine + Prober recorded into a session store.

For scripts, tests and benchmarks: hits are written (fsync'ed / committed) in the prober's listener, before
``probe(...).wait()`` returns them, and features are fitted exactly as on the station (it is the same model).
"""

from __future__ import annotations

from typing import Any

from .model import MeasurementModel, Part


def record(writer: Any, machine: Any, prober: Any, part: Part | None = None, *, port: str = "") -> MeasurementModel:
    """A measurement model journalling into ``writer`` (a store's session writer) the hits ``prober`` takes;
    its ``close()`` detaches it from the prober and closes the writer."""

    def probe(point: Any, approach: Any, clearance_z: float | None, client: Any = None,
              hop_z: float | None = None) -> Any:
        return prober.probe(point, approach, clearance_z=clearance_z)  # no rails to prove a hop: over clearance_z

    model = MeasurementModel(machine, prober, probe, part=part)
    model.record_into(writer, port=port)
    prober.listeners.append(model.add_hit)
    model.on_close(lambda: prober.listeners.remove(model.add_hit) if model.add_hit in prober.listeners else None)
    return model
