"""Part programs as files: the TOML program model (``cmm-program/1``, a taught program; ``/2``, a routine with its
ordered ``[[steps]]``), its geometric tolerances and the TOML text the station writes. Below the measurement
model and the sessions, which both read programs; the measurement model runs them (:mod:`cmm.measurement.program`,
:mod:`cmm.measurement.routine_run`)."""
