"""I++ DME 1.4.3 server in front of the station (commercial metrology software drives the CMM), and a client.

Layers: :mod:`protocol` (lines, tags, responses), :mod:`errors`, :mod:`tools`
and :mod:`csy` (state the spec defines), :mod:`executor` (queues, error
model, the command set), :mod:`backend` (the narrow machine interface and its
station implementation), :mod:`server` (TCP), :mod:`client`.
"""
