# Shared by scripts/demo, scripts/test and scripts/bench: make (once) and activate the
# project's virtual environment in .venv, with msleak installed in editable mode.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${MSLEAK_VENV:-$root/.venv}"
python="${PYTHON:-python3}"
if [ ! -x "$venv/bin/python" ]; then
    echo "msleak: creating virtual environment $venv" >&2
    "$python" -m venv "$venv"
fi
stamp="$venv/.msleak-installed"
if [ ! -f "$stamp" ] || [ "$root/pyproject.toml" -nt "$stamp" ]; then
    echo "msleak: installing msleak and its dependencies into $venv" >&2
    "$venv/bin/python" -m pip install --quiet --upgrade pip
    "$venv/bin/python" -m pip install --quiet -e "$root[test]"
    touch "$stamp"
fi
export PATH="$venv/bin:$PATH"
# numba compiles once and caches here, so repeated runs start fast
export NUMBA_CACHE_DIR="${NUMBA_CACHE_DIR:-$venv/numba-cache}"
