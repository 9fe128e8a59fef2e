"""The command API: commands, read-only queries and subscriptions, the one door every front end goes through.

Layers (imports go down only; see docs/architecture.md)::

    ui, pendant, I++ DME, OPC UA, DMIS, cli     front ends: they receive the API object, never the station
    station                                     composition root: builds the sides, registers their verbs
    control, measurement, calibration ...       register their verbs, queries and streams where they live
    api          <- this package: the registry, calls and responses, error codes, subscriptions, the caller

It imports no other part of ``cmm``: it knows verbs by name, never the machine or the measurement behind them.
:mod:`.commands`: :class:`CommandAPI` (``invoke`` in process, ``call`` / ``request`` for wire adapters,
``subscribe`` to queries at a bounded rate, ``listen`` to in-process event streams), :class:`Verb`,
:class:`Response`, :data:`ERROR_CODES`, :class:`CommandError`; :mod:`.subscriptions`: the subscription hub;
:mod:`.clients`: :class:`Client` (who calls) and :class:`AccessRefused`.
"""

from .clients import AccessRefused, Client, client_of
from .commands import ERROR_CODES, REQUIRED, CommandAPI, CommandError, Pending, Response, Stream, Verb, jsonable
from .subscriptions import Subscription, Subscriptions

__all__ = ["AccessRefused", "Client", "CommandAPI", "CommandError", "ERROR_CODES", "Pending", "REQUIRED", "Response",
           "Stream", "Subscription", "Subscriptions", "Verb", "client_of", "jsonable"]
