"""The predicted leakage beside an observation: the Stokes I power a simulation leaks
(the PS of a predicted column) against the Stokes I power observed (the PS of DATA) on the
same 2D bins (docs/leakage.md, "Predicted leakage against the observation")."""

from __future__ import annotations

import numpy as np
import xarray as xr

from msleak.errors import InputError
from msleak.leakage.expected import same_grid
from msleak.leakage.fraction import stokes_power

__all__ = ["compare_observed", "COMPARE_COLUMNS"]

#: the table's columns (after the input's label)
COMPARE_COLUMNS = ("window_leak", "window_observed", "window_ratio", "total_leak",
                   "total_observed", "total_ratio", "units")


def compare_observed(model: xr.Dataset, observed: xr.Dataset, model_name: str = "model",
                     observed_name: str = "observed") -> xr.Dataset:
    """Predicted leakage P_I (``model``, a PS product of a predicted column) and observed P_I
    (``observed``, a PS product of the observation) per 2D bin, their ratio, and the sums
    of each over the EoR window (k_par above the horizon wedge) and over every bin with
    power in both, each bin weighted by its number of 3D cells (the observation's counts).

    Raises
    ------
    InputError
        Products on different (k_par, k_perp) bins, or of different power units.
    """
    if not same_grid(model["k_par"].values, model["k_perp"].values,
                     observed["k_par"].values, observed["k_perp"].values):
        raise InputError(f"{observed_name} and {model_name} are on different (k_par, k_perp) "
                         "bins; make both PS products with the same grid, transform and ps "
                         "options")
    units = str(model["power"].attrs.get("units", ""))
    if units != str(observed["power"].attrs.get("units", "")):
        raise InputError(f"{observed_name} has power in "
                         f"{observed['power'].attrs.get('units', '?')!r}, {model_name} in "
                         f"{units!r}; make both with the same ps options")
    leak = np.real(stokes_power(model, "power", "I", model_name)
                   .transpose("k_par", "k_perp").values)
    obs = np.real(stokes_power(observed, "power", "I", observed_name)
                  .transpose("k_par", "k_perp").values)
    counts = (observed["counts"].transpose("k_par", "k_perp").values.astype(float)
              if "counts" in observed.variables else np.ones(obs.shape))
    valid = np.isfinite(leak) & np.isfinite(obs) & (obs > 0) & (counts > 0)
    ratio = np.where(valid, leak / np.where(valid, obs, 1.0), np.nan)
    slope = float(model.attrs.get("wedge_slope_horizon", np.nan))
    window = valid & (model["k_par"].values[:, None] > slope * model["k_perp"].values[None, :])
    sums = {}
    for name, inside in (("window", window), ("total", valid)):
        s_leak = float(np.sum(counts[inside] * leak[inside]))
        s_obs = float(np.sum(counts[inside] * obs[inside]))
        sums.update({f"{name}_leak": s_leak, f"{name}_observed": s_obs,
                     f"{name}_ratio": s_leak / s_obs if s_obs > 0 else float("nan")})
    dims = ("k_par", "k_perp")
    return xr.Dataset(
        {"power_leak": (dims, leak, {"units": units}),
         "power_observed": (dims, obs, {"units": units}),
         "ratio": (dims, ratio, {"units": "1"})},
        coords={"k_par": model["k_par"], "k_perp": model["k_perp"]},
        attrs={**sums, "units": units, "wedge_slope_horizon": slope,
               "model_input": model_name, "observed_input": observed_name,
               "weights": "each 2D bin weighted by the observation's 3D cells (counts)",
               "window": "k_par > wedge_slope_horizon k_perp (above the horizon wedge)"})
