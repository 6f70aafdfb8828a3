"""Typed options of predict, each default written once (docs/predict.md).

The verb :func:`msleak.predict`, the ``msleak predict`` options and the degridder take their
defaults from these classes; the classes check their values and name the parameter at fault.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from msleak.errors import InputError

__all__ = ["METHODS", "Method", "DegridOptions", "MIN_ELEVATION_DEG", "check_min_elevation",
           "check_extent"]

#: lowest elevation (deg) at which a pixel of an all-sky sky counts, by default
MIN_ELEVATION_DEG = 0.0

#: how pixel skies are predicted (:class:`DegridOptions`)
METHODS = ("auto", "direct", "degrid")
Method = Literal["auto", "direct", "degrid"]


@dataclass(frozen=True)
class DegridOptions:
    """How pixel skies are predicted, and to what accuracy.

    Parameters
    ----------
    method : {'auto', 'direct', 'degrid'}
        'direct' sums every pixel as a point source; 'degrid' uses image-domain gridding
        (pixel skies only); 'auto' degrids the pixel skies of at least
        :data:`msleak.predict.gridsky.AUTO_MIN_PIXELS` pixels where its modelled cost is lower.
    epsilon : float
        Requested relative accuracy of the degridder, 0 < epsilon < 1: it bounds the
        visibilities and their leaked Stokes I and V (docs/predict.md, "The leakage
        contract").
    nsub : int, optional
        Subgrid size (even, >= 8); None: from the beam's measured spectrum, at least 32.

    Raises
    ------
    InputError
        A value out of its range (the message names the parameter).
    """

    method: Method = "auto"
    epsilon: float = 1e-6
    nsub: int | None = None

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise InputError(f"unknown method {self.method!r}; use {', '.join(METHODS)}",
                             param="method")
        try:
            epsilon = float(self.epsilon)
        except (TypeError, ValueError):
            epsilon = float("nan")
        if not 0.0 < epsilon < 1.0:
            raise InputError(f"epsilon must be in (0, 1), got {self.epsilon}", param="epsilon")
        object.__setattr__(self, "epsilon", epsilon)
        nsub = self.nsub
        if nsub is not None:
            if isinstance(nsub, bool) or int(nsub) != nsub or nsub < 8 or nsub % 2:
                raise InputError(f"nsub must be an even integer >= 8, got {nsub}", param="nsub")
            object.__setattr__(self, "nsub", int(nsub))

    def settings(self) -> dict:
        """The options as run-state settings (None left out)."""
        return {k: v for k, v in (("method", self.method), ("epsilon", self.epsilon),
                                  ("nsub", self.nsub)) if v is not None}


def check_min_elevation(value) -> float:
    """``min_elevation`` (deg) checked: a number in [-90, 90).

    Raises
    ------
    InputError
        Not a number in that range.
    """
    try:
        degrees = float(value)
    except (TypeError, ValueError):
        degrees = float("nan")
    if not -90.0 <= degrees < 90.0:
        raise InputError(f"min_elevation must be in [-90, 90) deg, got {value}",
                         param="min_elevation")
    return degrees


def check_extent(value) -> float | None:
    """``extent`` (deg, None: the whole sky) checked: a number in (0, 180].

    Raises
    ------
    InputError
        Not a number in that range.
    """
    if value is None:
        return None
    try:
        degrees = float(value)
    except (TypeError, ValueError):
        degrees = float("nan")
    if not 0.0 < degrees <= 180.0:
        raise InputError(f"extent must be in (0, 180] deg, got {value}", param="extent")
    return degrees
