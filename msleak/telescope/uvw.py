"""Antenna and baseline UVW coordinates (J2000) from casacore measures.

Convention (the Measurement Set's, checked in the tests against TaQL ``mscal.uvwj2000``):
the UVW of the row (ANTENNA1 = p, ANTENNA2 = q) is ``uvw_q - uvw_p``, where ``uvw_a`` is
antenna a's position projected on the (u, v, w) axes of the J2000 phase centre, with the
baseline rotated from ITRF into the J2000 frame at the epoch of the integration.
"""

from __future__ import annotations

import numpy as np

from msleak.io.measures import set_epoch

__all__ = ["antenna_uvw"]


def antenna_uvw(positions_itrf: np.ndarray, times_mjd_s: np.ndarray, ra: float,
                dec: float) -> np.ndarray:
    """UVW (J2000, m) of every antenna relative to the first, at every time.

    Parameters
    ----------
    positions_itrf : (nant, 3) ITRF positions, m
    times_mjd_s : (ntime,) UTC epochs, MJD seconds
    ra, dec : J2000 phase centre, rad

    Returns
    -------
    (ntime, nant, 3) array, m. Baseline (p, q) has ``uvw[:, q] - uvw[:, p]``.
    """
    import casacore.measures as cm
    import casacore.quanta as qa

    positions_itrf = np.asarray(positions_itrf, dtype=float)
    rel = positions_itrf - positions_itrf[0]
    dm = cm.measures()
    dm.do_frame(dm.position("ITRF", *[qa.quantity(x, "m") for x in positions_itrf[0]]))
    dm.do_frame(dm.direction("J2000", qa.quantity(ra, "rad"), qa.quantity(dec, "rad")))
    baseline = dm.baseline("ITRF", qa.quantity(rel[:, 0], "m"), qa.quantity(rel[:, 1], "m"),
                           qa.quantity(rel[:, 2], "m"))
    out = np.empty((len(times_mjd_s), len(rel), 3))
    for k, t in enumerate(np.asarray(times_mjd_s, dtype=float)):
        set_epoch(dm, t)
        xyz = dm.to_uvw(baseline)["xyz"].get_value()
        out[k] = np.asarray(xyz, dtype=float).reshape(-1, 3)
    return out
