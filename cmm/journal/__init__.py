"""The session journal, on the bottom floor under the measurement model and the sessions, which both use it:

- :mod:`.records` and :mod:`.state`: the records a journal's events hold and their one fold
  (:class:`~.state.SessionState`): the live model folds what it journals, replay and re-evaluation a file's events;
- :mod:`.writer`: the append-only JSON Lines journal, fsync'ed per event, locked by its writer, and read back;
- :mod:`.store` and :mod:`.store_pg`: where journals live (a directory, or PostgreSQL with a local spool);
- :mod:`.session`: a recorded session read back from its events, and what a ``start`` event records of the
  machine and the part (:func:`~.session.machine_snapshot`, :func:`~.session.mesh_sha256`);
- :mod:`.wording`: the journal's events in an operator's words; :mod:`.bulk`: reading many journals at once.

It imports only the machine's configuration and metrology, never :mod:`cmm.measurement` nor :mod:`cmm.session`.
"""
