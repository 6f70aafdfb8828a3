"""Delay transform: per uv cell FFT along frequency.

:func:`delay_transform` windows (:func:`spectral_window`) and FFTs the visibilities of
every uv cell along frequency, with delays from :func:`delay_axis` (s, fftshift order,
0 central); it records ``window_norm`` so the power spectrum is window-independent for
white noise. Channels empty in every cell (:func:`channel_mask`) enter as zeros; cells
with partial channel coverage are dropped or zero-filled (``partial``).

The FFT convention and the treatment of empty channels: docs/transform.md.
"""

from __future__ import annotations

import logging
from typing import Literal

import numpy as np

from msleak.errors import InputError

__all__ = ["WINDOWS", "FFT_CONVENTION", "spectral_window", "delay_axis", "delay_transform",
           "channel_mask"]

log = logging.getLogger(__name__)

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
