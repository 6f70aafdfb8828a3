"""Fractional polarization leakage L_I from power spectra (docs/science.md, docs/leakage.md).

:mod:`~msleak.leakage.fraction`  L_I = 100 sqrt(P_I / P_P) per 2D bin and 3D voxel, masks
:mod:`~msleak.leakage.stats`     voxel statistics, histogram peak, Pareto (b = 1) fits
:mod:`~msleak.leakage.bootstrap` block-bootstrap errors over correlated voxels
:mod:`~msleak.leakage.expected`  expected leakage and bias correction, on arrays
:mod:`~msleak.leakage.observed`  the same for observed PS products, as Datasets
:mod:`~msleak.leakage.analysis`  the leakage result of several PS products (:func:`analyse`)

``msleak.leakage`` is both this package and, when called, the verb
:func:`msleak.verbs.leakage.leakage` (``msleak leakage``), which reads and writes the files.
"""

from msleak._callable import make_callable
from msleak.leakage.analysis import STAT_COLUMNS, analyse
from msleak.leakage.expected import (corrected_power, expected_leakage_error,
                                     expected_leakage_power, spherical_from_bins)
from msleak.leakage.fraction import (MASK_CODES, leakage_fraction, leakage_map,
                                     leakage_voxels)
from msleak.leakage.observed import bias_correct, expected_leakage
from msleak.leakage.stats import (ParetoFit, field_estimate, fit_pareto,
                                  fit_pareto_histogram, leakage_statistics,
                                  pareto_density_percent)

__all__ = [
    "MASK_CODES", "leakage_fraction", "leakage_map", "leakage_voxels",
    "ParetoFit", "fit_pareto", "fit_pareto_histogram", "leakage_statistics",
    "pareto_density_percent", "field_estimate",
    "expected_leakage_power", "expected_leakage_error", "corrected_power",
    "spherical_from_bins", "STAT_COLUMNS",
    "analyse", "expected_leakage", "bias_correct",
]


make_callable(__name__, "msleak.verbs.leakage:leakage")
