"""How the page reads: queries of the command API (:mod:`cmm.api`), never the station's objects.

One call form for reads, ``query(name, **params)``: a tab's :meth:`cmm.ui.context.PanelContext.query`, or
:func:`reader` of the command API itself (the shared 3-D view, the pure renderers, their tests; a bare model
without a control core is read through a bare :class:`cmm.api.CommandAPI` with
:func:`cmm.measurement.queries.register_queries` on it). The measurement model is
one :class:`~cmm.measurement.queries.ModelSnapshot` per refresh (the ``model`` query, copied under the model's
lock by the model's side), never the model's lock held by the page; what the page changes it changes with the
API's verbs (:meth:`cmm.ui.context.PanelContext.do`)."""

from __future__ import annotations

from typing import Any, Callable

from ..measurement.queries import ModelSnapshot

Query = Callable[..., Any]  # query(name, **params) -> the query's result


def reader(source: Any) -> Query:
    """``query(name, **params)`` of ``source``: a query function as it is, or anything with the command API's
    ``invoke`` (asked as the station's own client: queries are open to every client)."""
    if callable(source) and not hasattr(source, "invoke"):
        return source
    return lambda name, /, **params: source.invoke(None, name, **params)


def model_of(source: Any) -> ModelSnapshot:
    """The ``model`` query of ``source`` (see :func:`reader`)."""
    return reader(source)("model")


__all__ = ["ModelSnapshot", "Query", "model_of", "reader"]
