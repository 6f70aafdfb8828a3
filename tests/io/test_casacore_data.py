"""casacore's leap-second table from the IERS list (msleak.io.casacore_data).

The checks run casacore in child processes, each with its own cache and HOME, because
casacore reads its resource files once per process.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from datetime import datetime, timedelta
from pathlib import Path

import pytest

from msleak.io.casacore_data import (FRESHNESS_DAYS, casacore_root,
                                     configure_casacore_measures, leap_second_file,
                                     user_configured_casacore)

SEVERE = "Leap second table TAI_UTC seems out-of-date"

#: TAI - UTC (s) at UTC epochs, from the IERS list and casacore's pre-1972 formula
#: 3.54013 s + (MJD - 38761) * 0.001296 s (MJD 38761 = 1965-01-01).
KNOWN_TAI_UTC = {"1965-01-01T00:00:00": 3.54013, "1972-01-01T00:00:01": 10.0,
                 "2016-12-31T23:59:00": 36.0, "2017-01-01T00:00:01": 37.0}

_CONVERT = r"""
import sys, casacore.measures as cm, casacore.quanta as qa
dm = cm.measures()
for epoch in sys.argv[1:]:
    utc = dm.epoch("UTC", qa.quantity(epoch))
    tai = dm.measure(utc, "TAI")
    print(epoch, (tai["m0"]["value"] - utc["m0"]["value"]) * 86400.0)
"""


def _clean_env(tmp_path: Path) -> dict:
    env = {k: v for k, v in os.environ.items()
           if k not in ("AIPSPATH", "CASARCFILES", "CASACORE_DATADIR", "XDG_CACHE_HOME")}
    home = tmp_path / "home"
    home.mkdir(exist_ok=True)
    env.update(HOME=str(home), MSLEAK_CACHE_DIR=str(tmp_path / "cache"))
    return env


def _tai_minus_utc(env: dict, epochs) -> tuple[dict, str]:
    done = subprocess.run([sys.executable, "-c", _CONVERT, *epochs], env=env,
                          capture_output=True, text=True, check=True, timeout=120)
    values = {line.split()[0]: float(line.split()[1]) for line in done.stdout.splitlines()}
    return values, done.stderr


def _edited_list(tmp_path: Path, *, expires: str | None = None, extra: str | None = None,
                 change=None) -> Path:
    text = leap_second_file().read_text()
    if expires:
        text, n = re.subn(r"File expires on .*", f"File expires on {expires}", text)
        assert n == 1
    if change:
        text = text.replace(*change)
    if extra:
        text = text.rstrip("\n") + "\n" + extra + "\n"
    path = tmp_path / "Leap_Second.dat"
    path.write_text(text)
    return path


needs_data = pytest.mark.skipif(leap_second_file() is None or casacore_root() is None,
                                reason="astropy-iers-data or python-casacore not installed")


@needs_data
def test_a_simulate_prints_nothing_on_stderr(tmp_path):
    env = _clean_env(tmp_path)
    done = subprocess.run([sys.executable, "-m", "msleak", "simulate", str(tmp_path / "s.ms"),
                           "--stations", "CS00[12]HBA0", "--duration", "0.05", "--nchan", "2"],
                          env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""


@needs_data
def test_the_table_holds_the_list_and_casacore_converts_with_it(tmp_path):
    env = _clean_env(tmp_path)
    folder = configure_casacore_measures(env)
    assert folder is not None and env["AIPSPATH"] == str(folder)
    values, stderr = _tai_minus_utc(env, KNOWN_TAI_UTC)
    assert SEVERE not in stderr
    for epoch, expected in KNOWN_TAI_UTC.items():
        assert values[epoch] == pytest.approx(expected, abs=1e-6), epoch


@needs_data
def test_every_row_of_casacores_own_table_is_kept(tmp_path):
    import casacore.tables as pt

    env = _clean_env(tmp_path)
    folder = configure_casacore_measures(env)
    with pt.table(str(casacore_root() / "data" / "geodetic" / "TAI_UTC"), ack=False) as old, \
            pt.table(str(folder / "TAI_UTC"), ack=False) as new:
        assert new.info()["type"] == "IERS"
        assert new.nrows() >= old.nrows()
        for name in ("MJD", "dUTC", "Offset", "Multiplier"):
            assert list(new.getcol(name)[:old.nrows()]) == list(old.getcol(name)), name


@needs_data
def test_a_new_leap_second_in_the_list_reaches_casacore(tmp_path):
    # 2027-01-01 is MJD 61406; a list with a (made-up) 38th second must move TAI - UTC
    source = _edited_list(tmp_path, extra="    61406.0    1  1 2027       38")
    env = _clean_env(tmp_path)
    assert configure_casacore_measures(env, source=source) is not None
    values, _ = _tai_minus_utc(env, ["2026-12-31T12:00:00", "2027-01-01T12:00:00"])
    assert values["2026-12-31T12:00:00"] == pytest.approx(37.0, abs=1e-6)
    assert values["2027-01-01T12:00:00"] == pytest.approx(38.0, abs=1e-6)


@needs_data
def test_vs_date_is_the_expiry_less_casacores_freshness_window(tmp_path):
    import casacore.tables as pt

    source = _edited_list(tmp_path, expires="28 June 2031")
    env = _clean_env(tmp_path)
    folder = configure_casacore_measures(env, source=source)
    with pt.table(str(folder / "TAI_UTC"), ack=False) as table:
        keywords = table.getkeywords()
    expected = datetime(2031, 6, 28) - timedelta(days=FRESHNESS_DAYS)
    assert keywords["VS_DATE"] == expected.strftime("%Y/%m/%d/%H:%M")
    assert keywords["EXPIRES"] == "2031-06-28"


@needs_data
def test_an_expired_list_still_gets_casacores_warning(tmp_path):
    source = _edited_list(tmp_path, expires="28 June 2020")
    env = _clean_env(tmp_path)
    assert configure_casacore_measures(env, source=source) is not None
    _, stderr = _tai_minus_utc(env, ["2017-01-01T00:00:01"])
    assert SEVERE in stderr


@needs_data
def test_a_list_that_contradicts_casacore_is_not_used(tmp_path):
    source = _edited_list(tmp_path, change=("1  1 2017       37", "1  1 2017       39"))
    env = _clean_env(tmp_path)
    assert configure_casacore_measures(env, source=source) is None
    assert "AIPSPATH" not in env


@pytest.mark.parametrize("setting", ["CASARCFILES", "AIPSPATH", ".casarc", ".casa/rc",
                                     ".aipsrc"])
def test_a_users_own_casacore_configuration_is_left_alone(tmp_path, setting):
    env = _clean_env(tmp_path)
    home = Path(env["HOME"])
    if setting in ("CASARCFILES", "AIPSPATH"):
        env[setting] = str(tmp_path / "elsewhere")
    else:
        (home / setting).parent.mkdir(parents=True, exist_ok=True)
        (home / setting).write_text("measures.directory: /data/casa/measures\n")
    before = dict(env)
    assert user_configured_casacore(env)
    assert configure_casacore_measures(env) is None
    assert env == before


@needs_data
def test_python_casacores_own_aipspath_is_not_a_user_choice(tmp_path):
    env = _clean_env(tmp_path)
    env["AIPSPATH"] = str(casacore_root())      # what importing python-casacore first sets
    (Path(env["HOME"]) / ".casarc").write_text("table.endianformat: big\n")
    assert not user_configured_casacore(env)
    assert configure_casacore_measures(env) is not None
