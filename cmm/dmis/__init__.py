"""DMIS (ANSI/DMIS 105, ISO 22093) part programs on the station: check, run, output, export.

- :mod:`.lexer`, :mod:`.parser`: text -> statements (``$$`` comments, ``$`` continuation, labels, expressions);
- :mod:`.check`: the whole program checked before anything moves ("line N: X is not supported");
- :mod:`.executor`: the statements run on a target (:mod:`.runner`: the station, through its control core and
  measurement model), with :mod:`.frames` (coordinate systems), :mod:`.features` (FEAT nominals, FA actuals),
  :mod:`.construct` (CONST) and :mod:`.tolerances` (TOL, INTOL / OUTOL);
- :mod:`.export`: a taught program (``cmm-program/1``) written as a DMIS program;
- :mod:`.cli`: ``cmm run PROGRAM.dmi``.
"""
