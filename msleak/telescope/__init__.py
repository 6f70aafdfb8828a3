"""Telescopes on arrays: station layouts (LOFAR, SKA-Low, HERA, MWA, layout files),
observation plans and UVW; the MS itself is written by :mod:`msleak.io.ms_create`
(docs/simulate.md, docs/telescopes.md)."""
