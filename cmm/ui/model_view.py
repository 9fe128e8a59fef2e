"""The measurement model as the page reads it: a snapshot through the command API's ``model`` query
(:func:`cmm.measurement.queries.snapshot`), never the model's lock held by the page.

The page draws hits, features and constructions from one :class:`~cmm.measurement.queries.ModelSnapshot` per
refresh; what it changes it changes with the API's verbs (:meth:`cmm.ui.context.PanelContext.do`)."""

from __future__ import annotations

from typing import Any

from ..measurement.queries import ModelSnapshot, snapshot


def model_of(station: Any, client: Any = None) -> ModelSnapshot:
    """The ``model`` query of the station's command API as ``client`` (a query: open to every client); a bare
    model without a control core (the pure renderers' tests) is copied the same way."""
    api = getattr(getattr(station, "controller", None), "commands", None)
    if api is not None and any(v.name == "model" for v in api.queries()):
        return api.invoke(client, "model")
    return snapshot(station.measurement)


__all__ = ["ModelSnapshot", "model_of"]
