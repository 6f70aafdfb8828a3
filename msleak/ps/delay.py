"""Delay transform: per uv cell FFT along frequency.

:func:`delay_transform` windows (:func:`spectral_window`) and FFTs the visibilities of
every uv cell along frequency, with delays from :func:`delay_axis` (s, fftshift order,
0 central); it records ``window_norm`` so the power spectrum is window-independent for
white noise. Channels empty in every cell (:func:`channel_mask`) enter as zeros; cells
with partial channel coverage are dropped or zero-filled (``partial``).

:func:`delay_dataset` builds the delay product's Dataset from a uvcube Dataset. The FFT
convention and the treatment of empty channels: docs/transform.md.
"""

from __future__ import annotations

import logging
from typing import Literal

import numpy as np
import xarray as xr

from msleak.errors import InputError

__all__ = ["WINDOWS", "FFT_CONVENTION", "Partial", "spectral_window", "delay_axis",
           "delay_transform", "channel_mask", "delay_dataset"]

log = logging.getLogger(__name__)

#: cells empty in some unflagged channels: dropped, or those channels filled with zeros
Partial = Literal["drop", "zero"]

FFT_CONVENTION = ("V~(b,tau_k) = (1/N) sum_n w_n V(b,nu_n) exp(-2 pi i n k/N), "
                  "tau_k = k/(N dnu) s, k = -N/2..N/2-1 (fftshift order)")

#: window names -> scipy.signal.windows names (``none`` is all ones)
WINDOWS = {
    "none": None,
    "blackman-harris": "blackmanharris",
    "blackmanharris": "blackmanharris",
    "hann": "hann",
    "hamming": "hamming",
    "blackman": "blackman",
    "nuttall": "nuttall",
    "tukey": "tukey",
}


def spectral_window(name: str, n: int) -> np.ndarray:
    """The spectral window (n,) by name (``none``, ``blackman-harris``, ``hann``, ...).

    Windows are symmetric (``sym=True``) and peak at 1.
    """
    key = name.lower()
    if key not in WINDOWS:
        raise InputError(f"unknown window {name!r}: use one of {', '.join(sorted(WINDOWS))}")
    if WINDOWS[key] is None:
        return np.ones(n)
    from scipy.signal import windows

    return np.asarray(windows.get_window(WINDOWS[key], n, fftbins=False), dtype=float)


def delay_axis(nchan: int, chan_width_hz: float) -> np.ndarray:
    """Delays (nchan,) in s, fftshift order (0 at index nchan // 2)."""
    return np.fft.fftshift(np.fft.fftfreq(nchan, d=chan_width_hz))


def channel_mask(weight: np.ndarray) -> np.ndarray:
    """Channels (chan,) that hold data in at least one cell; ``weight`` is (chan, v, u)."""
    return (np.asarray(weight) > 0).reshape(weight.shape[0], -1).any(axis=1)


def delay_transform(vis: np.ndarray, weight: np.ndarray, window: np.ndarray, *,
                    partial: Literal["drop", "zero"] = "drop",
                    ) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """Delay-transform a uv cube.

    Parameters
    ----------
    vis : (..., chan, v, u) complex
        Gridded visibilities (any leading axes, e.g. stokes), Jy.
    weight : (chan, v, u) float
        Gridded weights; 0 = empty.
    window : (chan,) float
        Spectral window.
    partial : {'drop', 'zero'}
        What to do with cells empty in some of the unflagged channels.

    Returns
    -------
    vis_delay : (..., delay, v, u) complex
        V~ in Jy, delays in fftshift order (see :func:`delay_axis`).
    cell_weight : (v, u) float
        Sum of weights over channels; 0 for cells not used.
    window_norm : float
        ``sum (w m)^2 / N`` with m the mask of unflagged channels.
    chan_ok : (chan,) bool
        Unflagged channels.
    """
    vis = np.asarray(vis)
    weight = np.asarray(weight, dtype=float)
    nchan = weight.shape[0]
    if vis.shape[-3:] != weight.shape:
        raise InputError(f"uv cube shape {vis.shape} does not match weights {weight.shape}")
    if window.shape != (nchan,):
        raise InputError(f"window has {window.size} values for {nchan} channels")
    if partial not in ("drop", "zero"):
        raise InputError(f"unknown empty-cell policy {partial!r}: use 'drop' or 'zero'")
    chan_ok = channel_mask(weight)
    if not chan_ok.any():
        raise InputError("the uv cube is empty: every channel has zero weight")
    if not chan_ok.all():
        log.warning("%d of %d channels are empty in every cell (flagged); they enter the "
                    "delay transform as zeros", int((~chan_ok).sum()), nchan)
    filled = weight[chan_ok] > 0
    full = filled.all(axis=0)
    some = filled.any(axis=0)
    if partial == "drop":
        used = full
        n_partial = int((some & ~full).sum())
        if n_partial:
            log.info("dropped %d uv cells empty in some channels (partial='drop')", n_partial)
    else:
        used = some
    w_eff = window * chan_ok
    data = np.where(used & (weight > 0), vis, 0.0) * w_eff[:, None, None]
    out = np.fft.fftshift(np.fft.fft(data, axis=-3), axes=-3) / nchan
    cell_weight = np.where(used, weight.sum(axis=0), 0.0)
    window_norm = float(np.sum(w_eff ** 2) / nchan)
    return out, cell_weight, window_norm, chan_ok


def delay_dataset(uv: xr.Dataset, window: str = "blackman-harris",
                  partial: Partial = "drop") -> xr.Dataset:
    """The delay Dataset of a checked uvcube Dataset (see :func:`transform`)."""
    freq = uv["freq"].values
    nchan = freq.size
    if nchan < 2:
        raise InputError(f"the uv cube has {nchan} channel(s); a delay transform needs >= 2")
    dnu = float(np.median(np.diff(freq)))
    if not np.allclose(np.diff(freq), dnu, rtol=1e-6, atol=0):
        raise InputError("the uv cube channels are not evenly spaced")
    win = spectral_window(window, nchan)
    weight = uv["weight"].values
    if "vis_a" in uv:  # halves: a cell must hold data in both halves to be used
        weight = np.where((uv["weight_a"].values > 0) & (uv["weight_b"].values > 0), weight, 0)
    out = {}
    cell_weight = window_norm = chan_ok = None
    for name in [n for n in ("vis", "vis_a", "vis_b") if n in uv]:
        vt, cell_weight, window_norm, chan_ok = delay_transform(
            uv[name].values, weight, win, partial=partial)
        out[name] = (("stokes", "delay", "v", "u"), vt, {"units": uv[name].attrs.get("units",
                                                                                    "Jy")})
    out["weight"] = (("v", "u"), cell_weight, {"units": "1",
                                               "long_name": "sum of weights over channels"})
    out["window_values"] = (("freq",), win * chan_ok, {"units": "1"})
    ds = xr.Dataset(out, coords={
        "stokes": uv["stokes"].values, "delay": ("delay", delay_axis(nchan, dnu), {"units": "s"}),
        "v": ("v", uv["v"].values, {"units": "wavelengths"}),
        "u": ("u", uv["u"].values, {"units": "wavelengths"}),
        "freq": ("freq", freq, {"units": "Hz"})})
    ds.attrs.update(uv.attrs)
    for key in ("msleak_product", "created", "command"):
        ds.attrs.pop(key, None)
    ds.attrs.update({
        "window": window.lower(), "window_norm": window_norm,
        "window_norm_definition": "sum(window^2 * channel_mask) / nchan",
        "freq_centre_hz": float(0.5 * (freq[0] + freq[-1])), "bandwidth_hz": nchan * dnu,
        "nchan": nchan, "channel_width_hz": dnu, "fft_convention": FFT_CONVENTION,
        "flagged_channels": int((~chan_ok).sum()), "empty_cell_policy": partial,
        "n_cells_used": int((cell_weight > 0).sum()),
    })
    if ds.attrs["n_cells_used"] == 0:
        raise InputError("no uv cell holds data in every channel; give partial 'zero' or a "
                         "wider uv range", param="partial")
    return ds
