"""Parameters of the leakage study (``msleak paper``, docs/paper.md)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from msleak.adapters.spinifex_rm import is_model_spec, parse_model_spec
from msleak.errors import InputError

__all__ = ["StudyConfig", "Instrument", "check_extents", "FIELDS_OF_VIEW", "RESOLUTIONS",
           "PAPER_UV_RANGE", "OBSERVED_UV_RANGE", "SKY_FOV_DEG", "nyquist_npix"]

#: (label, crop in pixels of the 50-pixel 15-deg cube): the paper's 15, 9 and 4 deg fields
#: of view are 50, 28 and 16 pixels (0.3 deg pixels: 15, 8.4 and 4.8 deg a side).
FIELDS_OF_VIEW = (("15deg", 50), ("9deg", 28), ("4deg", 16))
#: ``--resolution`` of the study: the paper's sky and baselines, or those of observed data
RESOLUTIONS = ("paper", "observed")
#: baselines (wavelengths) gridded and in the power spectra, per resolution
PAPER_UV_RANGE = (30.0, 180.0)
OBSERVED_UV_RANGE = (30.0, 800.0)
#: side of the study's sky cube, deg (the largest field of view)
SKY_FOV_DEG = 15.0
#: the paper's sky: pixels a side of the 15-deg cube
_PAPER_NPIX = FIELDS_OF_VIEW[0][1]
#: lower end of the 1D PS's k_perp range, Mpc^-1 (the paper's, msleak ps's default)
_KPERP_1D_MIN = 0.02
#: channels of the study's MSs and sky (``msleak simulate`` and ``msleak sky`` defaults)
_FREQ_MIN_HZ, _CHAN_WIDTH_HZ, _NCHAN = 150e6, 195312.5, 50
#: --quick: stations, hours, seconds per resolution; the observed set's baselines reach
#: 800 wavelengths (CS002-CS004 and the CS02x/CS03x ring, 20 HBA fields)
_QUICK = {"paper": {"stations": "CS00[1-7]HBA*,CS01[13]HBA*", "duration": 2.0,
                    "interval": 600.0},
          "observed": {"stations": "CS00[2-4]HBA*,CS0[23]*HBA*", "duration": 2.0,
                       "interval": 600.0}}


def nyquist_npix(fov_deg: float, uv_max: float) -> int:
    """Pixels a side of a cube ``fov_deg`` wide whose pixels resolve baselines up to
    ``uv_max`` wavelengths: pixel <= 1 / (2 uv_max) rad, so n = ceil(2 uv_max fov_rad)."""
    return math.ceil(2.0 * uv_max * math.radians(fov_deg) - 1e-9)


def check_extents(extents, nside: int | None, quick: bool) -> tuple[tuple, int]:
    """The extents sorted and unique, and NSIDE (default 64; 16 ``quick``), or
    :class:`InputError`."""
    extents = tuple(sorted({float(e) for e in extents}))
    if any(not 0 < e <= 180 for e in extents):
        raise InputError(f"extents must lie in (0, 180] deg, got "
                         f"{','.join(f'{e:g}' for e in extents)}", param="extents")
    nside = (16 if quick else 64) if nside is None else int(nside)
    if nside < 1 or nside & (nside - 1):
        raise InputError(f"nside must be a power of 2, got {nside}", param="nside")
    return extents, nside


@dataclass(frozen=True)
class Instrument:
    """What a real observation adds, for the budget runs of ``msleak paper`` and ``msleak
    forecast`` (docs/paper.md, "The instrument's budget"): a CSV table of RMs, a model
    computed for the MS (``"spinifex"``, ``"ionex:PATH"``) or ``"random"`` (``random:N`` per
    realisation), beam errors without their seed
    (``"failed=F,rotation=DEG"``), thermal noise (SEFD, Jy); each is predicted ``seeds``
    times (a table or model once)."""

    ionosphere: str | None = None
    beam_errors: str | None = None
    noise_sefd: float | None = None
    seeds: int = 3

    def check(self) -> None:
        """Raise :class:`InputError` for settings predict would refuse."""
        if self.seeds < 1:
            raise InputError(f"instrument_seeds must be at least 1, got {self.seeds}",
                             param="instrument_seeds")
        if self.ionosphere is not None and self.ionosphere != "random" \
                and not Path(self.ionosphere).is_file():
            if not is_model_spec(self.ionosphere):
                raise InputError(f"ionosphere {self.ionosphere!r} is neither random, "
                                 "spinifex, ionex:PATH nor a CSV table of RMs",
                                 param="ionosphere")
            parse_model_spec(self.ionosphere)
        if self.beam_errors is not None:
            from msleak.beam.errors import BeamErrors

            if "seed" in self.beam_errors:
                raise InputError("the study draws beam_errors' seed per realisation: give "
                                 "failed, rotation, amplitude and phase only",
                                 param="beam_errors")
            BeamErrors.parse(self.beam_errors)
        if self.noise_sefd is not None and not self.noise_sefd > 0:
            raise InputError(f"noise_sefd must be positive (Jy), got {self.noise_sefd}",
                             param="noise_sefd")

    def runs(self) -> list[tuple[str, int, list]]:
        """``(kind, realisation, predict options)`` of the budget runs; the noise runs'
        options are empty (the noise is added to the ideal column)."""
        runs = []
        if self.ionosphere is not None:
            n = self.seeds if self.ionosphere == "random" else 1
            runs += [("ionosphere", r, ["--ionosphere", f"random:{r}" if
                                        self.ionosphere == "random" else self.ionosphere])
                     for r in range(1, n + 1)]
        if self.beam_errors is not None:
            runs += [("beam_errors", r, ["--beam-errors", f"{self.beam_errors},seed={r}"])
                     for r in range(1, self.seeds + 1)]
        if self.noise_sefd is not None:
            runs += [("noise", r, []) for r in range(1, self.seeds + 1)]
        return runs


@dataclass
class StudyConfig:
    """Parameters of the study; ``quick`` shrinks stations, times and channels.

    ``resolution`` is ``"paper"`` (a 50-pixel 15-deg sky, baselines 30-180 wavelengths)
    or ``"observed"`` (pixels that resolve 800 wavelengths, baselines 30-800, predicted by
    image-domain gridding; docs/paper.md "Observation resolution"). ``sky_fov_deg``
    (``"observed"`` only) shrinks the sky cube, keeping the pixel rule and scaling the
    crops with it, for small test runs [default 15].
    """

    outdir: Path
    quick: bool = False
    seed: int = 2018
    #: sky realisations: seeds ``seed``, ``seed + 1``, ... through the same MSs and beams
    seeds: int = 1
    fields: tuple = ("ncp", "3c196")
    beam: str = "everybeam"
    observed: dict = field(default_factory=dict)   # field -> (Q.fits, U.fits)
    stations: str | None = None      # overrides of the study's size
    duration_h: float | None = None
    interval_s: float | None = None
    nchan: int | None = None
    #: predict in complex128 arithmetic (docs/leakage.md, "The numerical floor")
    double: bool = True
    resolution: str = "paper"
    sky_fov_deg: float | None = None
    #: what a real observation adds (docs/paper.md, "The instrument's budget"): a CSV table
    #: of RMs, ``"spinifex"`` or ``"ionex:PATH"`` (a model for the MS, predicted once), or
    #: ``"random"`` (``random:N`` per realisation), beam errors without their
    #: seed (``"failed=F,rotation=DEG"``), thermal noise (SEFD, Jy); each is predicted
    #: ``instrument_seeds`` times (a CSV table once) at the largest field of view
    ionosphere: str | None = None
    beam_errors: str | None = None
    noise_sefd: float | None = None
    instrument_seeds: int = 3
    #: L_I against the sky's extent: all-sky HEALPix skies of ``nside`` predicted within
    #: each extent (deg from the phase centre) for every field; () for none
    extents: tuple = ()
    nside: int | None = None

    def __post_init__(self):
        self._check_instrument()
        self.extents, self.nside = check_extents(self.extents, self.nside, self.quick)
        if self.resolution not in RESOLUTIONS:
            raise InputError(f"unknown resolution {self.resolution!r}: "
                             f"{' or '.join(RESOLUTIONS)}")
        if self.sky_fov_deg is not None:
            if self.resolution == "paper":
                raise InputError("the paper resolution keeps the paper's 15 deg sky; "
                                 "sky_fov_deg needs resolution 'observed'")
            if not 0 < self.sky_fov_deg <= SKY_FOV_DEG:
                raise InputError(f"sky_fov_deg {self.sky_fov_deg:g}: must be within "
                                 f"0..{SKY_FOV_DEG:g} deg")

    @property
    def instrument(self) -> "Instrument":
        """The corruptions of the budget runs."""
        return Instrument(self.ionosphere, self.beam_errors, self.noise_sefd,
                          self.instrument_seeds)

    def _check_instrument(self) -> None:
        self.instrument.check()

    def corruptions(self) -> list[tuple[str, int, list]]:
        """``(kind, realisation, predict options)`` of the instrument's budget runs
        (:meth:`Instrument.runs`)."""
        return self.instrument.runs()

    @property
    def simulate_args(self) -> list:
        quick = _QUICK[self.resolution]
        given = {"stations": self.stations, "duration": self.duration_h,
                 "interval": self.interval_s}
        args = []
        for key, value in given.items():
            if value is None and self.quick:
                value = quick[key]
            if value is not None:
                args += [f"--{key}", str(value)]
        if self.nchan is not None:
            args += ["--nchan", str(self.nchan)]
        return args

    @property
    def allsky_args(self) -> list:
        """Band options of the all-sky skies (the MSs' channels)."""
        return [] if self.nchan is None else ["--nchan", str(self.nchan)]

    @property
    def realisations(self) -> list[int]:
        """The sky seeds of the study, the first one being ``seed``."""
        return [self.seed + k for k in range(self.seeds)]

    def suffix(self, seed: int) -> str:
        """File and column suffix of a realisation: none for the first seed."""
        return "" if seed == self.seed else f"_s{seed}"

    # -- resolution ---------------------------------------------------------------------

    @property
    def uv_range(self) -> tuple[float, float]:
        """Baselines (wavelengths) gridded and in the power spectra."""
        return PAPER_UV_RANGE if self.resolution == "paper" else OBSERVED_UV_RANGE

    @property
    def sky_fov(self) -> float:
        """Side of the sky cube, deg."""
        return SKY_FOV_DEG if self.sky_fov_deg is None else float(self.sky_fov_deg)

    @property
    def sky_npix(self) -> int:
        """Pixels a side of the sky cube: the paper's 50, or enough that the pixel
        resolves the longest baseline (:func:`nyquist_npix`)."""
        if self.resolution == "paper":
            return _PAPER_NPIX
        return nyquist_npix(self.sky_fov, self.uv_range[1])

    @property
    def fields_of_view(self) -> tuple:
        """``(label, pixels a side)`` of the 15, 9 and 4 deg fields of view: the paper's
        :data:`FIELDS_OF_VIEW`, or crops of the same sky angles (28 and 16 of the paper's
        0.3-deg pixels, scaled with ``sky_fov_deg``) at the finer pixel, each the nearest
        pixel count of the cube's parity, as ``msleak sky --crop --fov`` rounds."""
        if self.resolution == "paper":
            return FIELDS_OF_VIEW
        from msleak.sky.cube import crop_npix_for_fov

        npix = self.sky_npix
        pixel = self.sky_fov / npix
        return ((FIELDS_OF_VIEW[0][0], npix),) + tuple(
            (label, crop_npix_for_fov(self.sky_fov * paper_npix / _PAPER_NPIX, pixel, npix))
            for label, paper_npix in FIELDS_OF_VIEW[1:])

    def sky_args(self, seed: int) -> list:
        args = ["--seed", str(seed)]
        if self.resolution != "paper":
            args += ["--fov", f"{self.sky_fov:g}", "--npix", str(self.sky_npix)]
        if self.nchan is not None:
            args += ["--nchan", str(self.nchan)]
        return args

    @property
    def predict_args(self) -> list:
        """Predict options of the resolution: the observed skies by image-domain gridding
        (``--method auto``: degridding for skies of 6400 pixels or more) with a 6 GB
        working set, so that a chunk holds many times and the w-layer FFTs of a large sky
        are shared by all of them (docs/predict.md, "Speed")."""
        if self.resolution == "paper":
            return []
        return ["--method", "auto", "--memory-limit", "6GB"]

    @property
    def grid_args(self) -> list:
        """Grid options of the resolution (the paper's 30-180 is msleak grid's default)."""
        if self.resolution == "paper":
            return []
        return ["--uv-range", ",".join(f"{x:g}" for x in self.uv_range)]

    @property
    def kperp_1d(self) -> tuple[float, float] | None:
        """k_perp range (Mpc^-1) of the 1D PS: the paper's 0.02-0.1 (msleak ps's default,
        None), or, observed, from 0.02 to the k_perp of the longest baseline at the band
        centre (Planck18, as msleak ps), rounded up to 0.01: every gridded voxel."""
        if self.resolution == "paper":
            return None
        from msleak.ps.cosmology import cosmo_at

        nchan = _NCHAN if self.nchan is None else self.nchan
        centre = _FREQ_MIN_HZ + 0.5 * (nchan - 1) * _CHAN_WIDTH_HZ
        k_max = float(cosmo_at(centre).k_perp(self.uv_range[1]))
        return _KPERP_1D_MIN, math.ceil(k_max * 100 - 1e-9) / 100

    @property
    def ps_args(self) -> list:
        """ps options of the resolution: the 1D PS's k_perp range (:attr:`kperp_1d`)."""
        k = self.kperp_1d
        return [] if k is None else ["--kperp-1d", f"{k[0]:g},{k[1]:g}"]
