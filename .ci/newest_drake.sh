#!/usr/bin/env bash
# CI's other end (issue 45): the newest Drake doorlab admits, on a Python >= 3.12 (Drake 1.52
# and later need it), with the whole suite. .ci/run runs the README's commands first (the
# machine's python3: Python 3.11 here, Drake 1.51.1, the oldest supported), then this.
#
# The Python: the first of python3.12, python3.13, python3.14, python3 on PATH that is >= 3.12,
# else the oldest >= 3.12 under ~/.pyenv/versions; none: one line, exit 1. `--which` prints the
# one it would use and stops.
set -euo pipefail
cd "$(dirname "$0")/.."

is_new_enough() { "$1" -c 'import sys; sys.exit(sys.version_info < (3, 12))' 2>/dev/null; }

python=""
for name in python3.12 python3.13 python3.14 python3; do
  if command -v "$name" >/dev/null 2>&1 && is_new_enough "$(command -v "$name")"; then
    python=$(command -v "$name")
    break
  fi
done
if [ -z "$python" ]; then
  while IFS= read -r candidate; do
    if is_new_enough "$candidate"; then python=$candidate; break; fi
  done < <(ls -d "$HOME"/.pyenv/versions/3.*/bin/python 2>/dev/null | sort -V)
fi
if [ -z "$python" ]; then
  echo ".ci/newest_drake.sh: no Python >= 3.12 on PATH or under ~/.pyenv/versions: the newest Drake (1.52 on) needs one" >&2
  exit 1
fi
if [ "${1:-}" = "--which" ]; then echo "$python"; exit 0; fi

echo "== the newest Drake on $("$python" --version) ($python): set-up =="
rm -rf .venv-newest
"$python" -m venv .venv-newest
.venv-newest/bin/python -m pip install --quiet --upgrade pip
.venv-newest/bin/python -m pip install --quiet -e ".[test]"
.venv-newest/bin/python -c "from doorlab.runtime.drake_compat import drake_version; import sys; print('drake', drake_version(), 'python', sys.version.split()[0])"

echo "== the newest Drake: the whole suite =="
.venv-newest/bin/python -m pytest
