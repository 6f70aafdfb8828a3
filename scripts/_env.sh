# Shared by the scripts: make (once) and activate the project's virtual environment in .venv
# (MSLEAK_VENV overrides), with msleak installed in editable mode. A script that needs
# extras names them in msleak_extras (space-separated) before sourcing this file: none for
# msleak and its runtime dependencies only (scripts/demo, results, sensitivity), `test` for
# the test suite's peers too (scripts/test, bench, crosscheck). The stamp file
# .msleak-installed lists the extras installed, one a line; a script that needs one more
# installs it on top, so one .venv serves them all. A pyproject.toml newer than the stamp
# reinstalls msleak with the extras already there and those asked for.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${MSLEAK_VENV:-$root/.venv}"
python="${PYTHON:-python3}"
if [ ! -x "$venv/bin/python" ]; then
    echo "msleak: creating virtual environment $venv" >&2
    "$python" -m venv "$venv"
fi
stamp="$venv/.msleak-installed"
installed=""
[ -f "$stamp" ] && installed="$(cat "$stamp")"
reinstall=0
{ [ ! -f "$stamp" ] || [ "$root/pyproject.toml" -nt "$stamp" ]; } && reinstall=1
for extra in ${msleak_extras:-}; do
    grep -qxF "$extra" <<<"$installed" || reinstall=1
done
if [ "$reinstall" = 1 ]; then
    # the extras already there and those asked for, one a line, sorted
    extras="$(printf '%s\n' $installed ${msleak_extras:-} | sed '/^$/d' | sort -u)"
    spec="$root"
    [ -n "$extras" ] && spec="$root[$(paste -sd, <<<"$extras")]"
    echo "msleak: installing $spec (editable) and its dependencies into $venv" >&2
    "$venv/bin/python" -m pip install --quiet --upgrade pip
    # No .pyc for every module of every dependency (about 200 MB, most never imported):
    # Python writes one for each module it imports, on first use. Unless it may not
    # (PYTHONDONTWRITEBYTECODE set): then every process would compile them anew.
    compile=--no-compile
    [ -n "${PYTHONDONTWRITEBYTECODE:-}" ] && compile=--compile
    "$venv/bin/python" -m pip install --quiet "$compile" -e "$spec"
    printf '%s' "${extras:+$extras$'\n'}" >"$stamp"
fi
unset installed reinstall extra extras spec compile
export PATH="$venv/bin:$PATH"
# numba compiles once and caches here, so repeated runs start fast
export NUMBA_CACHE_DIR="${NUMBA_CACHE_DIR:-$venv/numba-cache}"
