"""Fractional polarization leakage L_I from power spectra (docs/science.md, docs/leakage.md).

:mod:`~msleak.leakage.fraction`  L_I = 100 sqrt(P_I / P_P) per 2D bin and 3D voxel, masks
:mod:`~msleak.leakage.stats`     voxel statistics, histogram peak, Pareto (b = 1) fits
:mod:`~msleak.leakage.expected`  expected leakage of an observed field, bias correction
:mod:`~msleak.leakage.analysis`  the above assembled as xarray Datasets
:mod:`~msleak.leakage.report`    ``msleak leakage``: read products, write tables/products/figures
"""

from msleak.leakage.analysis import analyse, correct, predict
from msleak.leakage.expected import (bias_correct, expected_leakage_error,
                                     expected_leakage_power, spherical_from_bins)
from msleak.leakage.fraction import (MASK_CODES, leakage_fraction, leakage_map,
                                     leakage_voxels)
from msleak.leakage.report import LeakageOptions, run_leakage
from msleak.leakage.stats import (ParetoFit, field_estimate, fit_pareto,
                                  fit_pareto_histogram, leakage_statistics,
                                  pareto_density_percent)

__all__ = [
    "MASK_CODES", "leakage_fraction", "leakage_map", "leakage_voxels",
    "ParetoFit", "fit_pareto", "fit_pareto_histogram", "leakage_statistics",
    "pareto_density_percent", "field_estimate",
    "expected_leakage_power", "expected_leakage_error", "bias_correct",
    "spherical_from_bins",
    "analyse", "predict", "correct", "LeakageOptions", "run_leakage",
]
