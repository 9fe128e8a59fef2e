"""The measurement model: what was measured and what it means, for every front end.

- :mod:`.records` and :mod:`.state`: the records a journal's events hold and their one fold
  (:class:`~.state.SessionState`): the live model folds what it journals, replay and re-evaluation a file's
  events; they import neither the rest of this package nor :mod:`cmm.session`, which imports them;
- :mod:`.model`: :class:`~.model.MeasurementModel`: the part, hits, features, undo, constructions,
  alignment pose, report header and the session journal they are written to;
- :mod:`.recording`: the same model on a bare Machine + Prober (scripts, tests, benchmarks);
- :mod:`.plan`: auto-measure: a feature planned at a picked face, probed and fitted;
- :mod:`.alignment`: 3-2-1 and best-fit alignment from measured features and hits;
- :mod:`.program`: running a taught program (:mod:`cmm.session.program`) on the model.

The station builds one model (``station.measurement``) and wires it to its control core; the viser panels,
the I++ server, replay and re-evaluation read and write the same records.
"""
