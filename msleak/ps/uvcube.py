"""The uvcube product's Dataset (docs/products.md "uvcube") from gridded Stokes arrays."""

from __future__ import annotations

from typing import Sequence

import numpy as np
import xarray as xr

from msleak.conventions import STOKES, STOKES_CONVENTION

__all__ = ["uvcube_dataset"]


def uvcube_dataset(vis4: np.ndarray, weight: np.ndarray, freq: np.ndarray,
                   centres: np.ndarray, attrs: dict,
                   halves: Sequence[tuple[np.ndarray, np.ndarray]] = ()) -> xr.Dataset:
    """Assemble a uvcube Dataset from I, Q, U, V grids; P = Q + iU is added.

    Parameters
    ----------
    vis4 : (4, chan, v, u) complex
        Gridded I, Q, U, V (Jy).
    weight : (chan, v, u) float
    freq : (chan,) Hz
    centres : (n,) cell centres, wavelengths (same for u and v)
    attrs : dict
        Attributes of the product.
    halves : up to two ``(vis4, weight)`` pairs stored as ``vis_a``/``vis_b`` and
        ``weight_a``/``weight_b``.
    """
    def five(v4):
        return np.concatenate([v4, (v4[1] + 1j * v4[2])[None]], axis=0)

    units = attrs.get("units", "Jy")
    dims = ("stokes", "freq", "v", "u")
    wattrs = {"units": "1", "long_name": "sum of the visibility weights"}
    data = {"vis": (dims, five(vis4), {"units": units,
                                       "long_name": "gridded Stokes visibility"}),
            "weight": (dims[1:], weight, wattrs)}
    for name, (hv, hw) in zip("ab", halves):
        data[f"vis_{name}"] = (dims, five(hv), {"units": units,
                                                "long_name": f"gridded Stokes visibility, "
                                                             f"time half {name}"})
        data[f"weight_{name}"] = (dims[1:], hw, wattrs)
    ds = xr.Dataset(data, coords={
        "stokes": ("stokes", list(STOKES), {"long_name": "Stokes parameter (P = Q + iU)"}),
        "freq": ("freq", np.asarray(freq, float), {"units": "Hz", "long_name": "frequency"}),
        "v": ("v", centres, {"units": "1", "long_name": "v of the cell centre, wavelengths"}),
        "u": ("u", centres, {"units": "1", "long_name": "u of the cell centre, wavelengths"}),
    })
    ds.attrs.update({"stokes_convention": STOKES_CONVENTION, "units": "Jy"})
    ds.attrs.update(attrs)
    return ds
