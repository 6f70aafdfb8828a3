"""Parameters of the leakage study (``msleak paper``, docs/paper.md)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["StudyConfig", "FIELDS_OF_VIEW"]

#: (label, crop in pixels of the 50-pixel 15-deg cube): the paper's 15, 9 and 4 deg fields
#: of view are 50, 28 and 16 pixels (0.3 deg pixels: 15, 8.4 and 4.8 deg a side).
FIELDS_OF_VIEW = (("15deg", 50), ("9deg", 28), ("4deg", 16))


@dataclass
class StudyConfig:
    """Parameters of the study; ``quick`` shrinks stations, times and channels."""

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

    @property
    def simulate_args(self) -> list:
        quick = {"stations": "CS00[1-7]HBA*,CS01[13]HBA*", "duration": 2.0, "interval": 600.0}
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
    def realisations(self) -> list[int]:
        """The sky seeds of the study, the first one being ``seed``."""
        return [self.seed + k for k in range(self.seeds)]

    def suffix(self, seed: int) -> str:
        """File and column suffix of a realisation: none for the first seed."""
        return "" if seed == self.seed else f"_s{seed}"

    def sky_args(self, seed: int) -> list:
        args = ["--seed", str(seed)]
        if self.nchan is not None:
            args += ["--nchan", str(self.nchan)]
        return args
