"""The whole leakage study (``msleak paper``), docs/paper.md.

:mod:`~msleak.study.config`    the study's parameters and fields of view
:mod:`~msleak.study.steps`     resumable steps (one msleak command line each)
:mod:`~msleak.study.pipeline`  the study's steps, run or resumed
:mod:`~msleak.study.report`    ``report.md``: figures, tables, estimates, commands
"""
