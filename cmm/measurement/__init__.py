"""The measurement model: what was measured and what it means, for every front end.

- the records a journal's events hold, their one fold and the journal's writer and stores are
  :mod:`cmm.journal`'s, below this package and :mod:`cmm.session`, which both use them; this package never
  imports :mod:`cmm.session` (a routine's report is written through the model's ``reporter``);
- :mod:`.model`: :class:`~.model.MeasurementModel`: the part, hits, features, undo, constructions,
  alignment pose, report header and the session journal they are written to;
- :mod:`.recording`: the same model on a bare Machine + Prober (scripts, tests, benchmarks);
- :mod:`.plan`: auto-measure: a feature planned at a picked face, probed and fitted;
- :mod:`.alignment`: 3-2-1 and best-fit alignment from measured features and hits;
- :mod:`.program`: running a taught program (:mod:`cmm.program.toml_program`) on the model;
- :mod:`.routine`, :mod:`.routine_path`, :mod:`.routine_run`: a routine (a program with ordered steps), the preview
  of its path and its run on the next part.

The station builds one model (``station.measurement``) and wires it to its control core; the viser panels,
the I++ server, replay and re-evaluation read and write the same records.
"""
