"""The verb :func:`leakage` (``msleak leakage``): reads PS products, runs the analysis
(:func:`msleak.leakage.analysis.analyse`), adds the expected leakage and bias correction of
observed products (:mod:`msleak.leakage.observed`) and writes the outputs
(:mod:`msleak.verbs.leakage_files`)."""

from __future__ import annotations

import logging
import os
from typing import Sequence, Union

import xarray as xr

from msleak.errors import InputError
from msleak.io.products import call_record, history_lines, open_product, stamp
from msleak.leakage.analysis import analyse
from msleak.leakage.compare import compare_observed
from msleak.leakage.fraction import NegativePolicy, StatsFrom
from msleak.leakage.observed import ModelMode, bias_correct, expected_leakage
from msleak.verbs.leakage_files import default_labels, refuse_existing, write_leakage

__all__ = ["leakage"]

log = logging.getLogger(__name__)

#: a PS product: its path, or the Dataset
PsInput = Union[str, os.PathLike, xr.Dataset]


def leakage(ps: PsInput | Sequence[PsInput], *, labels: Sequence[str] | None = None,
            realisations: Sequence[int] | None = None, field_name: str = "",
            stats_from: StatsFrom = "voxels",
            negative: NegativePolicy = "mask", bins: int = 100, hist_quantile: float = 0.99,
            k_par_range: tuple[float, float] | None = None,
            k_perp_range: tuple[float, float] | None = None,
            expected: PsInput | Sequence[PsInput] | None = None,
            expected_labels: Sequence[str] | None = None, expected_model: ModelMode = "auto",
            leakage_rel_error: float | None = None,
            correct: PsInput | Sequence[PsInput] | None = None,
            observed: PsInput | Sequence[PsInput] | None = None, n_boot: int = 200,
            bootstrap_block: int = 2, seed: int = 0, output: str | os.PathLike | None = None,
            overwrite: bool = False, figures: bool = True, pdf: bool = True) -> xr.Dataset:
    """Fractional leakage L_I = 100 sqrt(P_I / P_P) of PS products (``msleak leakage``).

    Parameters
    ----------
    ps : path or xarray.Dataset, or a sequence of them
        PS products (kind ``ps``), e.g. the fields of view of one field.
    labels, realisations, field_name, stats_from, negative, bins, hist_quantile,
    k_par_range, k_perp_range, expected_model, leakage_rel_error, n_boot,
    bootstrap_block, seed :
        As the options of ``msleak leakage`` (docs/leakage.md); k ranges in Mpc^-1.
    expected, correct : path or Dataset, or a sequence of them, optional
        Observed PS products: the expected leakage in them, and the bias correction of
        their Stokes I; written as ``expected_<label>.h5``, ``corrected_<label>.h5``, so
        they need ``output`` (in memory: :func:`~msleak.leakage.observed.expected_leakage`,
        :func:`~msleak.leakage.observed.bias_correct`).
    observed : path or Dataset, or a sequence of them, optional
        PS products of the observation (its DATA) on the inputs' bins, one for every input
        or one per input: the predicted leakage beside the observed Stokes I power, written
        as ``observed.csv`` and ``observed.png`` (in memory:
        :func:`msleak.leakage.compare.compare_observed`).
    output : path, optional
        Directory for stats.csv, estimates.csv, stats.md, leakage.h5 and the figures
        (PNG, and PDF with ``pdf``); None: return only.
    overwrite : bool
        Replace the products of an existing ``output``.

    Returns
    -------
    xarray.Dataset
        The content of leakage.h5: maps on (input, k_par, k_perp), the statistics table
        as variables on ``input`` (``result[list(STAT_COLUMNS)].to_dataframe()``, with
        :data:`msleak.leakage.STAT_COLUMNS`), histograms, per-realisation
        estimates; ``history`` holds the inputs' chains (docs/products.md).
    """
    given = dict(locals())
    inputs, obs_inputs, corr_inputs = _as_list(ps), _as_list(expected), _as_list(correct)
    labels, obs_labels = _check_options(
        len(inputs), labels, realisations, len(obs_inputs), len(corr_inputs), expected_labels,
        k_par_range, k_perp_range, hist_quantile, output)
    if output is not None:
        refuse_existing(output, overwrite)
    command = call_record(leakage, given)
    datasets, names = _open_all(inputs, "PS input")
    comparisons = _compare(datasets, names, _as_list(observed), output)
    observed, obs_names = _open_all(obs_inputs or corr_inputs, "observed PS")
    observed_i, corr_names = ((_open_all(corr_inputs, "observed PS") if obs_inputs
                               else (observed, obs_names)))
    labels = labels or default_labels(names)
    obs_labels = obs_labels or default_labels(obs_names)
    result = analyse(datasets, labels, names, stats_from=stats_from, negative=negative,
                     bins=bins, upper_quantile=hist_quantile, k_par_range=k_par_range,
                     k_perp_range=k_perp_range, field_name=field_name, n_boot=n_boot,
                     bootstrap_block=bootstrap_block, seed=seed, realisations=realisations)
    result = stamp(result, command, _input_history(datasets, labels))
    if output is None:
        return result
    exp_results, corr_results = _observed_results(
        result, observed, obs_labels, obs_names, observed_i if corr_inputs else [],
        corr_names, expected_model, leakage_rel_error)
    write_leakage(result, exp_results if obs_inputs else [], corr_results, output,
                  figures=figures, pdf=pdf, observed=comparisons)
    return result


def _compare(datasets: list, names: list, observed: list, output) -> list:
    """The predicted leakage of every input beside its observed PS (one for all, or one
    per input)."""
    if not observed:
        return []
    if output is None:
        raise InputError("the comparison with the observation is written to files: give "
                         "them a directory (output)", param=("observed", "output"))
    if len(observed) not in (1, len(datasets)):
        raise InputError(f"{len(observed)} observed PS for {len(datasets)} inputs; give one "
                         "for all or one per input", param="observed")
    obs, obs_names = _open_all(observed, "observed PS")
    pairs = [(j if len(obs) > 1 else 0) for j in range(len(datasets))]
    return [compare_observed(ds, obs[j], name, obs_names[j])
            for ds, name, j in zip(datasets, names, pairs)]


def _observed_results(result: xr.Dataset, observed, labels, names, observed_i, names_i,
                      mode: ModelMode, rel_error: float | None
                      ) -> tuple[list[xr.Dataset], list[xr.Dataset]]:
    """Expected leakage of every observed product and, if ``observed_i`` is given, the
    bias correction of their Stokes I; ``history``: the result's chain, then the observed
    products' chains, prefixed by ``[observed <label>]``."""
    expected, corrected = [], []
    for i, (obs, lab, name) in enumerate(zip(observed, labels, names)):
        exp = expected_leakage(result, obs, i, len(observed), mode, rel_error, name)
        # the inputs' chains (the result's, without its own line), then the observed one
        chain = history_lines(result.attrs)[:-1] + _input_history([obs], [f"observed {lab}"],
                                                              prefix_one=True)
        exp = stamp(exp.assign_attrs(label=lab), result.attrs["command"], chain)
        log.info("%s (%s): expected leakage from L_I model %s (%s, %.4g %%)", name, lab,
                 exp.attrs["model_input"], exp.attrs["model_mode"],
                 exp.attrs["L_I_model_scalar"])
        expected.append(exp)
        if observed_i:
            cor = bias_correct(observed_i[i], exp, names_i[i])
            if observed_i[i] is not obs:
                chain += _input_history([observed_i[i]], [f"observed I {lab}"],
                                        prefix_one=True)
            cor = stamp(cor.assign_attrs(label=lab), result.attrs["command"], chain)
            corrected.append(cor)
    return expected, corrected


def _as_list(items) -> list:
    if items is None:
        return []
    if isinstance(items, (str, os.PathLike, xr.Dataset)):
        return [items]
    return list(items)


def _open_all(items: Sequence[PsInput], what: str) -> tuple[list[xr.Dataset], list[str]]:
    """PS products from paths or Datasets, and a name for each (its path)."""
    datasets, names = [], []
    for i, item in enumerate(items):
        if isinstance(item, xr.Dataset):
            name = str(item.encoding.get("source", f"{what.replace(' ', '_')}{i + 1}"))
            if "power" not in item.variables:
                raise InputError(f"{name}: has no 'power'; give a ps product (msleak ps)")
            datasets.append(item)
        else:
            name = str(item)
            datasets.append(open_product(item, "ps", required=["power"]))
        names.append(name)
    return datasets, names


def _check_options(n_in: int, labels, realisations, n_obs: int, n_corr: int,
                   obs_labels, k_par_range, k_perp_range, hist_quantile: float, output
                   ) -> tuple[list[str] | None, list[str] | None]:
    """The checks of ``msleak leakage`` that need no file; returns the labels as lists."""
    if n_in == 0:
        raise InputError("no PS product given")
    labels = list(labels) if labels is not None else None
    if labels is not None and len(labels) != n_in:
        raise InputError(f"{len(labels)} labels for {n_in} PS inputs; give one label "
                         "per input")
    if realisations is not None and len(realisations) != n_in:
        raise InputError(f"{len(realisations)} realisations for {n_in} PS inputs; give one "
                         "realisation per input")
    if labels is not None:
        keys = list(zip(labels, realisations or [0] * n_in))
        if len(set(keys)) != len(keys):
            raise InputError(f"labels must be unique within a realisation, got "
                             f"{','.join(labels)}; choose other labels", param="labels")
    for option, rng in (("k_par_range", k_par_range), ("k_perp_range", k_perp_range)):
        if rng is not None and not (len(rng) == 2 and 0 <= rng[0] < rng[1]):
            raise InputError(f"{option} needs 0 <= MIN < MAX, got "
                             f"{','.join(f'{x:g}' for x in rng)}", param=option)
    if not 0.5 <= hist_quantile <= 1.0:
        raise InputError(f"hist_quantile must be in [0.5, 1], got {hist_quantile:g}",
                         param="hist_quantile")
    if n_obs and n_corr and n_obs != n_corr:
        raise InputError(f"correct pairs one to one with expected: got {n_corr} and "
                         f"{n_obs} files", param=("correct", "expected"))
    if (n_obs or n_corr) and output is None:
        raise InputError("the expected leakage and corrected spectra are written to files: "
                         "give them a directory (output)", param="output")
    obs_labels = list(obs_labels) if obs_labels is not None else None
    if obs_labels is not None:
        if len(obs_labels) != max(n_obs, n_corr):
            raise InputError(f"{len(obs_labels)} expected_labels for {max(n_obs, n_corr)} "
                             "observed PS products; give one per expected file",
                             param=("expected_labels", "expected"))
        if len(set(obs_labels)) != len(obs_labels):
            raise InputError(f"expected_labels must be unique, got {','.join(obs_labels)}",
                             param="expected_labels")
    return labels, obs_labels


def _input_history(datasets: Sequence[xr.Dataset], labels: Sequence[str],
                   prefix_one: bool = False) -> list[str]:
    """The ``history`` chain of the inputs: one input's chain as it is; for several,
    every input's chain in turn, each line prefixed by ``[label]``."""
    if len(datasets) == 1 and not prefix_one:
        return history_lines(datasets[0].attrs)
    return [f"[{label}] {line}" for ds, label in zip(datasets, labels)
            for line in history_lines(ds.attrs)]
