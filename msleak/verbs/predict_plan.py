"""Planning a predict run: the skies and their columns, the selected rows of each MS, the
skies evaluated per field and spectral window, and the chunk size (docs/predict.md).

Everything here reads; nothing writes. Every refusal of the input is raised here, before
the first write.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import pickle
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import xarray as xr

from msleak import __version__
from msleak.adapters.healpix import is_hdf5, is_healpix_fits, read_healpix
from msleak.adapters.sky_fits import cube_from_dataset, read_cube
from msleak.adapters.skymodel import read_skymodel
from msleak.conventions import correlation_layout
from msleak.errors import InputError
from msleak.io import columns as colio
from msleak.io.fits import is_fits
from msleak.io.ms import (
    iter_rows,
    open_table,
    read_antennas,
    read_corr_types,
    read_data_descriptions,
    read_fields,
    read_spectral_windows,
    read_used_antennas,
)
from msleak.predict.components import SkySet, sky_components, sky_set
from msleak.predict.horizon import Horizon
from msleak.predict.options import MIN_ELEVATION_DEG, DegridOptions, check_extent
from msleak.sky.cube import SkyCube
from msleak.sky.healpix import HealpixSky
from msleak.sky.sources import PointSources
from msleak.verbs.predict_chunks import register_beam

__all__ = ["PredictResult", "Target", "Plan", "make_targets", "make_plan"]

log = logging.getLogger(__name__)

@dataclass
class PredictResult:
    """What a predict run did for one column of one MS."""

    ms: Path
    column: str | None
    rows_written: int
    groups: list = field(default_factory=list)
    resumed: bool = False
    created_column: bool = False
    #: the column was complete from an identical run and left as it was
    skipped: bool = False
    seconds: float = 0.0
    #: directions with flux of this column's sky, per group
    n_sources: dict = field(default_factory=dict)
    #: wall time (s) per stage of the run on this MS, all its columns together (the same
    #: dict for each): setup (inputs, skies, beam model), read, uvw, beam, kernel,
    #: per_baseline, write
    timings: dict = field(default_factory=dict)
    #: number of time slots predicted
    n_slots: int = 0
    #: rows predicted from their own UVW (not antenna-based within the tolerance)
    rows_per_baseline: int = 0
    #: rms (Jy) of the real and imaginary parts of the thermal noise added, if any
    noise_sigma_jy: float | None = None


@dataclass(frozen=True)
class Target:
    """One sky of a run, read once (a :class:`SkyCube`, :class:`PointSources` or
    :class:`HealpixSky`), and the column it is predicted into (None: returned in memory);
    ``path`` the file it was read from (None: given in memory); ``extent_deg`` keeps its
    sources within that angle of the phase centre."""

    sky: SkyCube | PointSources | HealpixSky
    column: str | None
    fov_deg: float | None
    sha256: str
    path: Path | None = None
    given: str = ""
    extent_deg: float | None = None

    @property
    def label(self) -> str:
        return str(self.path) if self.path is not None else f"<in-memory {self.given}>"


@dataclass(frozen=True)
class Plan:
    """What to predict into one MS: its metadata, selected groups, skies and settings,
    fixed before the first write (the run's state is :class:`msleak.verbs.predict_run.Run`)."""

    ms: Path
    fields_meta: list
    spw_meta: list
    ddesc: list
    groups: list
    feeds: dict
    total_rows: int
    targets: list
    skies: dict
    settings: list
    settings_json: list
    beam_token: str
    beam_options: dict = field(default_factory=dict)
    #: new columns are created complex128 (casacore DComplex)
    double_column: bool = False


def make_targets(sky, column, fov, overwrite_data: bool, extent=None,
                 flat_spectrum: bool = False) -> list[Target]:
    """The run's skies with their columns, fields of view and extents, matched in order
    and checked; ``flat_spectrum``: a HEALPix map of one frequency holds at every channel.

    ``column`` None (or a list of None) means the visibilities are returned, not written.
    """
    skies = list(sky) if isinstance(sky, (list, tuple)) else [sky]
    columns = list(column) if isinstance(column, (list, tuple)) else [column] * (
        len(skies) if column is None else 1)
    fovs = list(fov) if np.ndim(fov) == 1 else [fov]
    extents = _per_sky(extent, len(skies), "extent")
    if not skies:
        raise InputError("no sky given; give one as `sky`", param="sky")
    if len(columns) != len(skies):
        raise InputError(f"{len(skies)} `sky` and {len(columns)} `column` given; give one "
                         "`column` per `sky` (they are matched in order)",
                         param=("sky", "column"))
    if len(fovs) == 1:
        fovs = fovs * len(skies)
    if len(fovs) != len(skies):
        raise InputError(f"`fov` is given {len(fovs)} times for {len(skies)} `sky`; give it "
                         "once (for every sky) or once per `sky` (matched in order)",
                         param=("fov", "sky"))
    names = [c for c in columns if c is not None]
    if names and len(names) != len(columns):
        raise InputError("give every sky a column, or none (column=None returns the "
                         "visibilities)")
    for name in names:
        colio.check_column_name(name, overwrite_data=overwrite_data)
    for name in names:
        if names.count(name) > 1:
            raise InputError(f"`column` {name} is given {names.count(name)} times; give "
                             "every `sky` its own `column`", param=("column", "sky"))
    for value in fovs:
        if value is not None and not (0 < value <= 180):
            raise InputError(f"fov must be in (0, 180] deg, got {value}", param="fov")
    read: dict = {}
    return [Target(sky=_read_sky(s, read, flat_spectrum), column=c,
                   fov_deg=None if f is None else float(f), sha256=_digest(s),
                   path=s if isinstance(s, Path) else None, given=type(s).__name__,
                   extent_deg=e)
            for s, c, f, e in zip(_sky_inputs(skies), columns, fovs, extents)]


def _per_sky(value, nsky: int, name: str) -> list:
    """``value`` (one, or one per sky) as one checked extent per sky."""
    values = list(value) if np.ndim(value) == 1 else [value]
    if len(values) == 1:
        values = values * nsky
    if len(values) != nsky:
        raise InputError(f"`{name}` is given {len(values)} times for {nsky} `sky`; give it "
                         "once (for every sky) or once per `sky` (matched in order)",
                         param=(name, "sky"))
    return [check_extent(v) for v in values]


def _sky_inputs(skies: list) -> list:
    """Sky paths as Paths (checked to be files); in-memory skies as they are."""
    out = []
    for sky in skies:
        if isinstance(sky, (str, os.PathLike)):
            sky = Path(sky)
            if not sky.exists():
                raise InputError(f"sky file {sky} does not exist")
            if sky.is_dir():
                raise InputError(f"sky {sky} is a directory, not a FITS cube, HEALPix map, "
                                 "SkyH5 or makesourcedb file")
        out.append(sky)
    return out


def _read_sky(sky, read: dict, flat_spectrum: bool = False
              ) -> SkyCube | PointSources | HealpixSky:
    """A sky file read (once per path, cached in ``read``), a sky Dataset converted; a
    SkyCube, PointSources or HealpixSky as it is. Files are told apart by content: HDF5
    is SkyH5, FITS with a HEALPix header a HEALPix map, other FITS a cube, text
    makesourcedb (docs/sky.md)."""
    if isinstance(sky, Path):
        key = sky.resolve()
        if key not in read:
            read[key] = _read_file(sky, flat_spectrum)
        return read[key]
    if isinstance(sky, xr.Dataset):
        return cube_from_dataset(sky)
    if isinstance(sky, (SkyCube, PointSources, HealpixSky)):
        return sky
    raise InputError(f"sky must be a path, a sky Dataset (msleak.make_sky), a SkyCube, "
                     f"PointSources or HealpixSky, not {type(sky).__name__}")


def _read_file(path: Path, flat_spectrum: bool):
    """The sky in the file ``path`` (see :func:`_read_sky`)."""
    if is_hdf5(path) or is_healpix_fits(path):
        return read_healpix(path, flat_spectrum=flat_spectrum)
    if path.suffix.lower() in (".skyh5", ".h5", ".hdf5"):
        raise InputError(f"{path} is not an HDF5 file, so not SkyH5; give a SkyH5 file "
                         "pyradiosky wrote, a FITS cube or map, or a makesourcedb file")
    return read_cube(path) if is_fits(path) else read_skymodel(path)


def _digest(sky) -> str:
    """SHA-256 of a sky file's bytes, or of an in-memory sky's pickle."""
    digest = hashlib.sha256()
    if not isinstance(sky, Path):
        digest.update(pickle.dumps(sky, protocol=4))
        return digest.hexdigest()
    with open(sky, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def select_ids(values, names: list[str], what: str, present: np.ndarray) -> list[int]:
    """FIELD/SPW selection by id or name (one value or a sequence); default all ids present
    in the main table."""
    present = sorted(int(v) for v in np.unique(present))
    if values is None or (isinstance(values, (list, tuple)) and not values):
        return present
    out = []
    for v in (values if isinstance(values, (list, tuple)) else [values]):
        text = str(v).strip()
        if text.lstrip("-").isdigit():
            idx = int(text)
        elif text in names:
            idx = names.index(text)
        else:
            raise InputError(f"no {what} {text!r} in the MS (available: "
                             f"{', '.join(f'{i}:{n}' if n else str(i) for i, n in enumerate(names))})")
        if not 0 <= idx < len(names):
            raise InputError(f"no {what} {idx} in the MS (ids 0..{len(names) - 1})")
        if idx not in present:
            raise InputError(f"{what} {idx} has no rows in the MS (present: "
                             f"{', '.join(map(str, present))})")
        out.append(idx)
    return sorted(set(out))


def _row_groups(ms: Path) -> dict[tuple[int, int], int]:
    """Number of main-table rows of every (FIELD_ID, DATA_DESC_ID) present."""
    counts: dict[tuple[int, int], int] = {}
    for _, cols in iter_rows(ms, ["FIELD_ID", "DATA_DESC_ID"], chunk_rows=1_000_000):
        pairs, n = np.unique(np.stack([cols["FIELD_ID"], cols["DATA_DESC_ID"]], axis=1),
                             axis=0, return_counts=True)
        for (f, d), k in zip(pairs, n):
            counts[(int(f), int(d))] = counts.get((int(f), int(d)), 0) + int(k)
    return counts


def _select_groups(ms: Path, fields_meta, spw_meta, ddesc, field_sel, spw_sel
                   ) -> tuple[list, int]:
    """The selected (FIELD_ID, DATA_DESC_ID) groups in order, and their number of rows."""
    counts = _row_groups(ms)
    present = np.array(sorted(counts), dtype=int).reshape(-1, 2)
    field_ids = select_ids(field_sel, [f.name for f in fields_meta], "field", present[:, 0])
    spw_present = np.unique([ddesc[d][0] for d in np.unique(present[:, 1])])
    spw_ids = select_ids(spw_sel, [s.name for s in spw_meta], "spectral window", spw_present)
    groups = [(f, d) for f, d in sorted(counts) if f in field_ids and ddesc[d][0] in spw_ids]
    if not groups:
        raise InputError(f"{ms}: no rows match the field / spectral-window selection")
    return groups, int(sum(counts[g] for g in groups))


def make_plan(ms: Path, targets: list, *, beam, centre_correction, interpolate_frequency,
              dtype, field_sel, spw_sel, beam_options: dict, double_column: bool = False,
              degrid: DegridOptions = DegridOptions(),
              min_elevation: float = MIN_ELEVATION_DEG, flat_spectrum: bool = False) -> Plan:
    """Read the metadata of ``ms``, select its groups and prepare the skies (no writes);
    ``double_column``: the columns are, or are created, complex128; ``degrid``: how pixel
    skies are predicted; ``min_elevation`` (deg): the horizon of HEALPix skies, seen from
    the array centre; ``flat_spectrum`` is recorded (the targets were read with it)."""
    fields_meta, spw_meta = read_fields(ms), read_spectral_windows(ms)
    ddesc, corr_types = read_data_descriptions(ms), read_corr_types(ms)
    _check_new_columns(ms, [t.column for t in targets if t.column is not None], double_column)
    groups, total_rows = _select_groups(ms, fields_meta, spw_meta, ddesc, field_sel, spw_sel)
    feeds = {d: correlation_layout(corr_types[ddesc[d][1]]) for _, d in groups}
    for d in sorted({d for _, d in groups if not feeds[d].full}):
        log.warning("%s: data description %d has only the correlations %s; predict computes "
                    "the full coherency and writes those two (the cross hands are not "
                    "stored)", ms, d, ",".join(feeds[d].names))
    _check_rows(ms, groups)
    all_sky = any(isinstance(t.sky, HealpixSky) for t in targets)
    probe = beam != "none" and degrid.method != "direct"     # the degridder's zenith probe
    array = _array_site(ms, groups) if all_sky or probe else (None, 0.0)
    site = array if probe else (None, 0.0)
    horizon = (Horizon(float(np.radians(min_elevation)), tuple(float(x) for x in array[0]))
               if all_sky else None)
    skies = {(f, d): _group_skies(targets, fields_meta[f], spw_meta[ddesc[d][0]].freq,
                                  interpolate_frequency, degrid, site,
                                  _field_text(ms, fields_meta, f), horizon)
             for f, d in groups}
    token = uuid.uuid4().hex
    options = register_beam(token, beam, ms, groups, beam_options)
    common = {"beam": beam, "centre_correction": bool(centre_correction and beam != "none"),
              "interpolate_frequency": bool(interpolate_frequency),
              "precision": dtype.name, "groups": [f"f{f}_d{d}" for f, d in groups],
              **degrid.settings(),
              "beam_options": dict(sorted(beam_options.items())),
              "msleak_version": __version__}
    healpix = {"min_elevation_deg": float(min_elevation), "flat_spectrum": bool(flat_spectrum)}
    settings = [{"sky": str(t.path.resolve()) if t.path is not None else t.label,
                 "sky_sha256": t.sha256,
                 "fov_deg": -1.0 if t.fov_deg is None else t.fov_deg,
                 "extent_deg": -1.0 if t.extent_deg is None else t.extent_deg, **common,
                 **(healpix if isinstance(t.sky, HealpixSky) else {})}
                for t in targets]
    return Plan(ms=ms, fields_meta=fields_meta, spw_meta=spw_meta, ddesc=ddesc,
                groups=groups, feeds=feeds, total_rows=total_rows, targets=targets,
                skies=skies, settings=settings,
                settings_json=[json.dumps(s, sort_keys=True) for s in settings],
                beam_token=token, beam_options=options, double_column=double_column)


def _field_text(ms: Path, fields_meta: list, f: int) -> str:
    """``ms``, or ``ms field F (NAME)`` when it has several fields: where a phase centre
    comes from, in the re-centring warning."""
    if len(fields_meta) < 2:
        return str(ms)
    name = getattr(fields_meta[f], "name", "")
    return f"{ms} field {f}" + (f" ({name})" if name else "")


def _array_site(ms: Path, groups: list) -> tuple[np.ndarray, float]:
    """Mean ITRF position (m) of the antennas in the selected rows, and the largest angle
    (rad) between one's geodetic zenith and the mean position's."""
    from msleak.beam.coords import enu_basis

    used = np.unique(np.concatenate([read_used_antennas(ms, f, d) for f, d in groups]))
    positions = read_antennas(ms).positions[used]
    site = positions.mean(axis=0)
    up = enu_basis(site)[2]
    cos = [float(np.dot(enu_basis(x)[2], up)) for x in positions]
    return site, float(np.arccos(np.clip(min(cos), -1.0, 1.0)))


def _group_skies(targets: list, fmeta, freq: np.ndarray, interpolate: bool,
                 degrid: DegridOptions,
                 site: tuple, phase_centre_of: str = "", horizon: Horizon | None = None
                 ) -> SkySet:
    """The skies of one field and spectral window (each (sky, fov, extent) read once);
    ``phase_centre_of`` names the field in the re-centring warning; ``horizon`` culls
    HEALPix skies."""
    comps: dict = {}
    for t in targets:
        key = _sky_key(t)
        if key not in comps:
            comps[key] = sky_components(t.sky, freq, fmeta.ra, fmeta.dec, label=t.label,
                                        fov_deg=t.fov_deg, interpolate=interpolate,
                                        degrid=degrid, site=site[0], site_spread=site[1],
                                        phase_centre_of=phase_centre_of,
                                        extent_deg=t.extent_deg, horizon=horizon)
    return sky_set([comps[_sky_key(t)] for t in targets])


def _sky_key(target: Target) -> tuple:
    return (id(target.sky), target.fov_deg, target.extent_deg)


def _check_new_columns(ms: Path, columns: list[str], double: bool) -> None:
    """Refuse target columns of the wrong kind, and new columns that fit on the disk one by
    one but not together."""
    with open_table(ms) as table:
        new = [c for c in columns if not colio.check_data_column(table, c, double=double)]
        if len(new) < 2:
            return
        cell_bytes = (16 if double else 8) * int(np.prod(table.getcell("DATA", 0).shape)) if table.nrows() else 0
        colio.check_free_space(table.name(), len(new) * (table.nrows() * cell_bytes
                                                         + 1.1 * 2**20),
                               f"columns {', '.join(new)}")


def _check_rows(ms: Path, groups: list) -> None:
    """Refuse rows predict cannot compute (TIME or UVW not finite), before any write."""
    for f, d in groups:
        for rows, cols in iter_rows(ms, ["TIME", "UVW"], field_id=f, ddid=d,
                                    chunk_rows=1_000_000):
            bad = ~(np.isfinite(cols["TIME"]) & np.isfinite(cols["UVW"]).all(axis=1))
            if bad.any():
                raise InputError(
                    f"{ms}: {int(bad.sum())} rows of field {f}, data description {d} have a "
                    f"TIME or UVW that is not a finite number (first: row {int(rows[bad][0])}); "
                    "delete them first (TaQL: DELETE FROM <ms> WHERE NOT (isfinite(TIME) && "
                    "all(isfinite(UVW)))) or leave that field or spectral window out with "
                    "`field` / `spw`", param=("field", "spw"))
