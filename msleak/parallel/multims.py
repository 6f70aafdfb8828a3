"""Several Measurement Sets as one band: channels in frequency order, gaps and overlaps.

LOFAR writes one Measurement Set per subband. :func:`frequency_layout` puts the channels of
several inputs on one regular frequency axis (pure function on the channel centres and
widths): inputs are sorted by frequency; channels that overlap another input's are an
error; a gap of a whole number of channels is filled with empty channels (weight 0, which
the delay transform treats as flagged channels) and reported; anything else (different
channel widths, a gap that is not a whole number of channels, uneven channels) is an error
because the delay transform needs one regular axis.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from msleak.errors import InputError

__all__ = ["FrequencyLayout", "frequency_layout", "RTOL"]

log = logging.getLogger(__name__)

#: relative tolerance (of the channel width) of frequency comparisons
RTOL = 1e-6


@dataclass(frozen=True)
class FrequencyLayout:
    """Where each input's channels go on the combined axis.

    Attributes
    ----------
    freq : (nchan,) float
        Channel centres of the combined axis, Hz (regular).
    width : float
        Channel spacing, Hz.
    order : list of int
        Input indices in frequency order.
    offsets : list of int
        ``offsets[i]``: index on the combined axis of input ``i``'s first channel.
    gaps : list of (float, float)
        Centre frequencies (Hz) of the first and last missing channel of each gap.
    """

    freq: np.ndarray
    width: float
    order: list
    offsets: list
    gaps: list = field(default_factory=list)

    @property
    def n_gap_channels(self) -> int:
        return int(sum(round((hi - lo) / self.width) + 1 for lo, hi in self.gaps))

    def gap_text(self) -> str:
        """Gaps as ``"lo-hi MHz"`` pieces, '' if none."""
        return ", ".join(f"{lo / 1e6:.6g}-{hi / 1e6:.6g} MHz" for lo, hi in self.gaps)


def _spacing(freq: np.ndarray, name: str) -> float:
    if freq.size < 2:
        return float("nan")
    step = np.diff(freq)
    if not np.allclose(step, step[0], rtol=RTOL, atol=0) or step[0] <= 0:
        raise InputError(f"{name}: channels are not evenly spaced in increasing frequency; "
                         "the delay transform needs a regular frequency axis")
    return float(step[0])


def frequency_layout(freqs: Sequence[np.ndarray], names: Sequence[str],
                     widths: Sequence[np.ndarray] | None = None) -> FrequencyLayout:
    """Combine the channel axes of several inputs into one regular axis.

    Parameters
    ----------
    freqs : sequence of (nchan_i,) float
        Channel centres of each input, Hz.
    names : sequence of str
        Input names for messages (MS paths).
    widths : sequence of (nchan_i,) float, optional
        CHAN_WIDTH of each input, Hz; used as the spacing of single-channel inputs.

    Returns
    -------
    FrequencyLayout

    Raises
    ------
    InputError
        Overlapping inputs, different channel spacings, gaps that are not a whole number
        of channels, or uneven channels within an input.
    """
    if not freqs:
        raise InputError("no input")
    freqs = [np.asarray(f, dtype=float).ravel() for f in freqs]
    for f, name in zip(freqs, names):
        if f.size == 0:
            raise InputError(f"{name}: the spectral window has no channels")
    steps = [_spacing(f, n) for f, n in zip(freqs, names)]
    if widths is not None:
        steps = [s if np.isfinite(s) else float(np.abs(np.asarray(w, float)).ravel()[0])
                 for s, w in zip(steps, widths)]
    known = [s for s in steps if np.isfinite(s)]
    if not known:
        raise InputError("cannot tell the channel spacing of single-channel inputs without "
                         "their channel widths")
    width = known[0]
    for s, name in zip(steps, names):
        if np.isfinite(s) and abs(s - width) > RTOL * width:
            raise InputError(f"{name}: channel spacing {s:.6g} Hz differs from "
                             f"{width:.6g} Hz of {names[steps.index(width)]}; the inputs must "
                             "share one channel width")
    order = sorted(range(len(freqs)), key=lambda i: freqs[i][0])
    for a, b in zip(order, order[1:]):
        if freqs[b][0] < freqs[a][-1] + width * (1 - RTOL):
            raise InputError(
                f"{names[b]} ({freqs[b][0] / 1e6:.6g}-{freqs[b][-1] / 1e6:.6g} MHz) overlaps "
                f"{names[a]} ({freqs[a][0] / 1e6:.6g}-{freqs[a][-1] / 1e6:.6g} MHz); give each "
                "channel once")
    f0 = freqs[order[0]][0]
    offsets = [0] * len(freqs)
    gaps = []
    prev_end = None
    for i in order:
        pos = (freqs[i][0] - f0) / width
        k = int(round(pos))
        if abs(pos - k) > 1e-3:
            raise InputError(f"{names[i]} starts {pos - int(pos):.3f} channels off the grid of "
                             f"{names[order[0]]}; the inputs' channels must lie on one regular "
                             "axis")
        offsets[i] = k
        if prev_end is not None and k > prev_end + 1:
            gaps.append((f0 + (prev_end + 1) * width, f0 + (k - 1) * width))
        prev_end = k + freqs[i].size - 1
    nchan = prev_end + 1
    freq = f0 + width * np.arange(nchan)
    for i in order:  # every channel on the combined grid
        exact = freq[offsets[i]:offsets[i] + freqs[i].size]
        if not np.allclose(exact, freqs[i], rtol=0, atol=1e-3 * width):
            raise InputError(f"{names[i]}: channels drift off the common grid")
    layout = FrequencyLayout(freq=freq, width=width, order=order, offsets=offsets, gaps=gaps)
    if gaps:
        log.warning("%d channel(s) missing between the inputs (%s): they are left empty "
                    "(weight 0) and enter the delay transform as flagged channels",
                    layout.n_gap_channels, layout.gap_text())
    return layout
