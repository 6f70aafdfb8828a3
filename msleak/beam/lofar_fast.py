"""The fast LOFAR HBA beam: EveryBeam's station response, vectorised.

What EveryBeam does per call (see :mod:`msleak.beam.lofar_kernels` for the formula) is
done here for all directions, channels and stations of a time slot at once:

1. directions -> ITRF once per time slot (:func:`msleak.beam.coords.itrf_map`, casacore
   anchors), the sky basis from the converted J2000 pole exactly as EveryBeam builds it;
2. the Hamaker element response through ``everybeam.ElementResponse`` on arrays, once per
   group of antenna fields with identical coordinate axes (all LOFAR core HBA fields share
   one), with EveryBeam's ``phi - 5 pi / 4`` dipole orientation and its rotation to the sky
   (North, East) basis;
3. tile (16 elements, towards LOFAR_TILE_BEAM_DIR; a 4 x 4 lattice is summed as a row sum
   times a column sum, :func:`lattice_factors`) and station (tiles, towards DELAY_DIR)
   array factors and the field phase-reference weights in numba.

Element gain errors per feed (:func:`msleak.beam.errors.perturb_lofar`) replace step 3 by a
sum over every element of every tile per feed (:mod:`msleak.beam.lofar_gain_kernels`).

Accuracy against EveryBeam and speed: docs/beam.md ("Validation", "Speed").
"""

from __future__ import annotations

import logging

import numpy as np

from msleak._everybeam import import_everybeam
from msleak.beam.base import BeamModel, JonesFactors
from msleak.beam.coords import clip_pole, itrf_map, radec_to_unit, sky_basis
from msleak.beam.lofar_array import LofarArray
from msleak.beam.lofar_gain_kernels import combine_feed_jones, gain_factors_kernel
from msleak.beam.lofar_kernels import combine_jones, station_factors_kernel
from msleak.errors import InputError

__all__ = ["LofarFastBeam", "element_jones", "sky_rotation", "field_angles",
           "lattice_factors"]

log = logging.getLogger(__name__)



def field_angles(axes: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hamaker (theta, phi) of ITRF directions ``d`` (ndir, 3) in a field frame, and ``d`` there.

    ``phi`` includes EveryBeam's ``- 5 pi / 4`` orientation of the LOFAR dipoles.
    """
    dl = d @ axes.T
    theta = np.pi / 2 - np.arctan2(dl[:, 2], np.hypot(dl[:, 0], dl[:, 1]))
    phi = np.arctan2(dl[:, 1], dl[:, 0]) - 1.25 * np.pi
    return theta, phi, dl


def sky_rotation(axes: np.ndarray, d: np.ndarray, north: np.ndarray, east: np.ndarray
                 ) -> np.ndarray:
    """EveryBeam's rotation (ndir, 2, 2) from a field's (theta, phi) basis to (North, East).

    ``R = [[e_theta.n, e_theta.e], [e_phi.n, e_phi.e]]`` with ``e_phi = normalize(z x d)``
    and ``e_theta = e_phi x d`` in the field frame; a Jones matrix in the (theta, phi)
    basis ``H`` becomes ``H @ R``.  At the field zenith the ``phi = 0`` limit is used.
    """
    dl = d @ axes.T
    nl = north @ axes.T
    el = east @ axes.T
    e_phi = np.stack([-dl[:, 1], dl[:, 0], np.zeros(len(dl))], axis=-1)
    e_phi[np.hypot(dl[:, 0], dl[:, 1]) < 1e-12] = (0.0, 1.0, 0.0)
    e_phi /= np.linalg.norm(e_phi, axis=-1, keepdims=True)
    e_theta = np.cross(e_phi, dl)
    rot = np.empty((len(dl), 2, 2))
    rot[:, 0, 0] = np.einsum("ij,ij->i", e_theta, nl)
    rot[:, 0, 1] = np.einsum("ij,ij->i", e_theta, el)
    rot[:, 1, 0] = np.einsum("ij,ij->i", e_phi, nl)
    rot[:, 1, 1] = np.einsum("ij,ij->i", e_phi, el)
    return rot


def element_jones(response, axes: np.ndarray, freq: np.ndarray, d: np.ndarray,
                  north: np.ndarray, east: np.ndarray) -> np.ndarray:
    """Hamaker element Jones of an antenna field in the sky (North, East) basis.

    Parameters
    ----------
    response : everybeam.ElementResponse
    axes : (3, 3) array
        Field axes p, q, r (rows, ITRF).
    freq : (nchan,) array, Hz
    d, north, east : (ndir, 3) arrays
        ITRF direction and its sky basis vectors.

    Returns
    -------
    (nchan, ndir, 2, 2) complex128
        Zero where the direction is below the field's horizon.
    """
    theta, phi, dl = field_angles(axes, d)
    rot = sky_rotation(axes, d, north, east)
    nchan, ndir = freq.size, len(dl)
    h = np.asarray(response.response(np.repeat(freq, ndir), np.tile(theta, nchan),
                                     np.tile(phi, nchan))).reshape(nchan, ndir, 2, 2)
    out = h[..., :, :1] * rot[None, :, :1, :] + h[..., :, 1:] * rot[None, :, 1:, :]  # h @ rot
    out[:, dl[:, 2] < 0] = 0
    return out


#: Largest difference (m, per coordinate) of an element from the product lattice
#: :func:`lattice_factors` fits: a phase error below 2 pi sqrt(3) 1e-9 / lambda, 1e-8 rad
#: at HBA frequencies.
LATTICE_TOL = 1e-9


def lattice_factors(offsets: np.ndarray, tol: float = LATTICE_TOL
                    ) -> tuple[np.ndarray, np.ndarray] | None:
    """Tile element offsets as a product lattice: ``offsets[i * n1 + j] = a[i] + b[j]``.

    The tile array factor of such a layout with equal weights is the product of the
    averages over ``a`` and over ``b``: n0 + n1 terms instead of n0 n1 (a LOFAR HBA tile,
    4 x 4 dipoles 1.25 m apart, is 8 instead of 16).

    Parameters
    ----------
    offsets : (n, 3) float
        Element offsets (m) in the order of the MS.
    tol : float
        Largest difference (m, per coordinate) of any offset from ``a[i] + b[j]``.

    Returns
    -------
    (a, b) with shapes (n0, 3), (n1, 3), n0 n1 = n and n0 + n1 smallest, or None when no
    split into two factors of at least two offsets fits (the elements are then summed
    one by one).
    """
    offsets = np.asarray(offsets, dtype=np.float64)
    n = len(offsets)
    best = None
    for n1 in range(2, n // 2 + 1):
        if n % n1:
            continue
        grid = offsets.reshape(n // n1, n1, 3)
        a = grid[:, 0]
        b = grid[0] - grid[0, 0]
        if np.abs(grid - (a[:, None] + b[None])).max() <= tol and (
                best is None or n // n1 + n1 < len(best[0]) + len(best[1])):
            best = (a, b)
    return best


def _tile_layout_arrays(layouts: list[np.ndarray]
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``layout_pos, layout_w, layout_n`` of :func:`station_factors_kernel` for tile element
    offsets ``layouts`` (each (n, 3), m): two factors where :func:`lattice_factors` finds
    them, else the elements alone."""
    nelem = max([1] + [len(e) for e in layouts])
    pos = np.zeros((len(layouts), 2, nelem, 3))
    weight = np.zeros((len(layouts), 2, nelem))
    count = np.zeros((len(layouts), 2), dtype=np.int64)
    for i, elem in enumerate(layouts):
        for k, part in enumerate(lattice_factors(elem) or (elem,)):
            pos[i, k, :len(part)] = part
            weight[i, k, :len(part)] = 1.0 / len(part)
            count[i, k] = len(part)
    return pos, weight, count


def _gain_arrays(fields: list, tile_w: np.ndarray, layouts: list[np.ndarray],
                 field_layout: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """``layout_pos, weights`` of :func:`gain_factors_kernel` for antenna ``fields`` with
    their normalised tile weights ``tile_w`` (nfield, ntile) and tile element ``layouts``,
    or None when no field has ``element_gains``: the weight of element ``e`` of tile ``t``
    for feed ``p`` is ``tile_w[t] g[t, e, p] / nelem`` (``g = 1`` for a field without
    gains), the model's own normalisation."""
    if all(f.element_gains is None for f in fields):
        return None
    nelem = max(len(e) for e in layouts)
    pos = np.zeros((len(layouts), nelem, 3))
    for i, elem in enumerate(layouts):
        pos[i, :len(elem)] = elem
    weights = np.zeros((len(fields), 2, tile_w.shape[1], nelem), complex)
    for n, f in enumerate(fields):
        ntile, ne = len(f.tile_offsets), len(layouts[field_layout[n]])
        gains = np.ones((ntile, ne, 2)) if f.element_gains is None else f.element_gains
        if gains.shape != (ntile, ne, 2):
            raise InputError(f"element gains of field {f.name} have shape {gains.shape}, "
                             f"not ({ntile}, {ne}, 2)")
        weights[n, :, :ntile, :ne] = np.moveaxis(gains, 2, 0) * (tile_w[n, :ntile, None] / ne)
    return pos, weights


def _uniform_step(freq: np.ndarray) -> tuple[bool, float]:
    if freq.size < 2:
        return True, 0.0
    df = (freq[-1] - freq[0]) / (freq.size - 1)
    ideal = freq[0] + df * np.arange(freq.size)
    return bool(np.max(np.abs(freq - ideal)) < 1e-3), float(df)


class LofarFastBeam(BeamModel):
    """LOFAR HBA station beams evaluated like EveryBeam's ``station_response``, vectorised.

    Parameters
    ----------
    array : LofarArray
        From :func:`msleak.adapters.beams.read_lofar_array`.
    element_model : str
        EveryBeam element model name; only ``hamaker`` is supported by the fast path.
    used_stations : int array, optional
        The stations the beam is for (default all).

    Fields with ``element_gains`` (errors of the model, :func:`msleak.beam.errors.perturb_lofar`)
    make the X and Y array factors differ: every element of every tile is then summed
    (slower; no :meth:`jones_factors`, docs/beam.md "Beam-model errors").
    """

    name = "everybeam"

    def __init__(self, array: LofarArray, element_model: str = "hamaker", used_stations=None):
        if element_model != "hamaker":
            raise InputError(f"the fast LOFAR beam supports the 'hamaker' element model only, "
                             f"not {element_model!r}; use `beam='everybeam-direct'`")
        if any(f.name == "LBA" for s in array.stations for f in s.fields):
            raise InputError("the fast LOFAR beam handles HBA fields only; this MS has LBA "
                             "fields: use `beam='everybeam-direct'`")
        super().__init__(len(array.stations), array.phase_centre,
                         [s.name for s in array.stations], used_stations)
        eb = import_everybeam()
        self.array = array
        fields = [(i, s, f) for i, s in enumerate(array.stations) for f in s.fields]
        nfield = len(fields)
        ntile = max(len(f.tile_offsets) for _, _, f in fields)
        self._field_station = np.array([i for i, _, _ in fields], dtype=np.int64)
        self._field_scale = np.array([1.0 / len(s.fields) for _, s, _ in fields])
        self._field_up = np.array([f.axes[2] for _, _, f in fields])
        self._tile_pos = np.zeros((nfield, ntile, 3))
        self._tile_w = np.zeros((nfield, ntile))
        groups: dict[bytes, int] = {}
        layouts: dict[bytes, int] = {}
        self._group_axes: list[np.ndarray] = []
        self._group_response = []
        self._field_group = np.zeros(nfield, dtype=np.int64)
        self._field_layout = np.zeros(nfield, dtype=np.int64)
        layout_pos: list[np.ndarray] = []
        for n, (_, s, f) in enumerate(fields):
            # EveryBeam dots positions and directions in the field frame: A x . A y
            metric = f.axes.T @ f.axes
            # the field phase reference factor exp(-i k (s0 - d).(origin - reference))
            # joins the tile array factor: positions from the station phase reference
            self._tile_pos[n, :len(f.tile_offsets)] = (f.tile_offsets @ metric + f.origin
                                                       - s.phase_reference)
            enabled = f.tile_enabled.astype(float)
            if enabled.sum() == 0:
                log.warning("station %s field %s has every tile flagged", s.name, f.name)
            else:
                self._tile_w[n, :len(enabled)] = enabled / enabled.sum()
            elem = np.ascontiguousarray(f.element_offsets @ metric)
            key = elem.tobytes()  # its length tells the number of elements
            if key not in layouts:
                layouts[key] = len(layout_pos)
                layout_pos.append(elem)
            self._field_layout[n] = layouts[key]
            key = np.round(f.axes, 12).tobytes()
            if key not in groups:
                groups[key] = len(self._group_axes)
                self._group_axes.append(f.axes)
                self._group_response.append(eb.ElementResponse.create("hamaker", s.name))
            self._field_group[n] = groups[key]
        self._layout_pos, self._layout_w, self._layout_n = _tile_layout_arrays(layout_pos)
        self._gains = _gain_arrays([f for _, _, f in fields], self._tile_w, layout_pos,
                                   self._field_layout)
        log.info("fast LOFAR beam: %d stations, %d fields, %d element-response groups",
                 self.n_stations, nfield, len(self._group_axes))

    def _directions(self, time: float, ra: np.ndarray, dec: np.ndarray):
        u = radec_to_unit(ra, clip_pole(dec))
        s0u = radec_to_unit(self.array.delay_dir[0], clip_pole(self.array.delay_dir[1]))
        t0u = radec_to_unit(self.array.tile_beam_dir[0], clip_pole(self.array.tile_beam_dir[1]))
        fitmap = itrf_map(time, np.vstack([u, s0u, t0u]))
        d = fitmap(u)
        s0, t0 = fitmap(s0u), fitmap(t0u)
        return d, s0, t0, fitmap.pole()

    def _jones(self, time, freq, ra, dec, stations, dtype):
        out = np.empty((stations.size, time.size, freq.size, ra.size, 2, 2), dtype)
        if out.size == 0:
            return out
        slots = self._slots(stations)
        feeds = () if self._gains is None else (2,)   # one factor per feed with gains
        factors = np.empty((stations.size, slots[3].shape[1], *feeds, freq.size, ra.size),
                           np.complex128)
        combine = combine_jones if self._gains is None else combine_feed_jones
        for it, t in enumerate(time):
            ej = self._slot_factors(float(t), freq, ra, dec, slots, factors)
            combine(factors, slots[3], ej, out[:, it])
        return out

    def _jones_factors(self, time, freq, ra, dec, stations, dtype):
        if self._gains is not None:
            return None  # X and Y array factors differ: no scalar factor per station
        slots = self._slots(stations)
        slot_groups = slots[3]
        if slot_groups.shape[1] > 1:
            return None  # a station whose fields have different element responses
        group = np.maximum(slot_groups[:, 0], 0)  # a station without fields: zero factor
        scalar = np.zeros((stations.size, time.size, freq.size, ra.size), dtype)
        element = np.zeros((len(self._group_axes), time.size, freq.size, ra.size, 2, 2),
                           dtype)
        if scalar.size == 0:
            return JonesFactors(scalar, element, group)
        for it, t in enumerate(time):
            element[:, it] = self._slot_factors(float(t), freq, ra, dec, slots,
                                                scalar[:, it, None])
        return JonesFactors(scalar, element, group)

    def _slots(self, stations) -> tuple:
        """The kernel's per-station layout of ``stations``: (slot_fields, slot_ptr,
        field_sub, slot_groups), with slot_groups (nstation, nsub) the distinct element
        groups of each station's fields (-1 padded, nsub >= 1) and field_sub the index
        there of every entry of slot_fields."""
        per_station = [np.flatnonzero(self._field_station == s) for s in stations]
        groups = [np.unique(self._field_group[f]) for f in per_station]
        slot_groups = np.full((len(stations), max([1] + [g.size for g in groups])), -1,
                              dtype=np.int64)
        for i, g in enumerate(groups):
            slot_groups[i, :g.size] = g
        field_sub = np.concatenate(
            [np.zeros(0, np.int64)] + [np.searchsorted(g, self._field_group[f])
                                       for f, g in zip(per_station, groups)]).astype(np.int64)
        slot_ptr = np.concatenate([[0], np.cumsum([len(f) for f in per_station])]).astype(np.int64)
        slot_fields = np.concatenate([np.zeros(0, np.int64)] + per_station).astype(np.int64)
        return slot_fields, slot_ptr, field_sub, slot_groups

    def _slot_factors(self, time: float, freq, ra, dec, slots, factors) -> np.ndarray:
        """Array factors (nstation, nsub, nchan, ndir) of one time slot per station and
        element group of its fields (``slots`` from :meth:`_slots`), written into
        ``factors`` ((nstation, nsub, 2, nchan, ndir), per feed, with gains); returns the element Jones matrices (ngroup, nchan, ndir, 2, 2) (zero
        for groups no station uses)."""
        slot_fields, slot_ptr, field_sub, slot_groups = slots
        uniform, df = _uniform_step(freq)
        d, s0, t0, ncp = self._directions(time, ra, dec)
        north, east = sky_basis(d, ncp)
        ej = np.zeros((len(self._group_axes), freq.size, ra.size, 2, 2), complex)
        for g in np.unique(self._field_group[slot_fields]):
            ej[g] = element_jones(self._group_response[g], self._group_axes[g], freq, d,
                                  north, east)
        if self._gains is not None:
            elem_pos, weights = self._gains
            gain_factors_kernel(d, s0, t0, freq, uniform, df, slot_fields, slot_ptr,
                                field_sub, self._field_layout, self._field_scale,
                                self._field_up, self._tile_pos, elem_pos, weights, factors)
            return ej
        station_factors_kernel(d, s0, t0, freq, uniform, df, slot_fields, slot_ptr,
                               field_sub, self._field_layout, self._field_scale,
                               self._field_up, self._tile_pos,
                               self._tile_w, self._layout_pos, self._layout_w,
                               self._layout_n, factors)
        return ej
