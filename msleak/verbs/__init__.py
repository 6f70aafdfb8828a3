"""The verbs: each reads its inputs (through :mod:`msleak.io`), runs one stage on arrays
(the computation packages sky, beam, predict, ps and leakage), and writes its products and
figures. The command line (:mod:`msleak.cli`) and the study (:mod:`msleak.study`) call
these, never the other way round (docs/architecture.md)."""
