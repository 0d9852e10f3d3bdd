#!/usr/bin/env bash
# Set up everything the tests need on a fresh Debian machine and run them:
# Debian's linuxcnc-uspace (the LinuxCNC interpreter used as an oracle) and chromium (the
# report in a real browser), a virtual
# environment with sdit-path and its test extras, then pytest.
set -euo pipefail
cd "$(dirname "$0")/.."

as_root() { if [ "$(id -u)" -eq 0 ]; then "$@"; else sudo "$@"; fi; }

# linuxcnc-uspace: LinuxCNC's interpreter and motion planner for the oracle tests;
# chromium and poppler-utils: the report opened, shot and printed in a real browser
NEED=""
for pkg in linuxcnc-uspace chromium poppler-utils; do
    dpkg -s "$pkg" >/dev/null 2>&1 || NEED="$NEED $pkg"
done
if [ -n "$NEED" ]; then
    echo "== installing Debian's$NEED"
    as_root apt-get update -qq
    # shellcheck disable=SC2086
    DEBIAN_FRONTEND=noninteractive as_root apt-get install -y -qq $NEED >/dev/null
fi

PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
    echo "== creating .venv"
    "$PY" -m venv .venv
fi
echo "== installing sdit-path and test dependencies"
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e '.[test]'

echo "== lint (ruff) and types (mypy on config, nc, reading and the effect library)"
.venv/bin/ruff check sdit_path postprocessors tests bench validation
.venv/bin/mypy

echo "== running the tests"
# two workers on the machine's two cores, each with one BLAS thread: numpy's threads
# gave nothing here (the diagnosis's self-check took 41 s with them, 37 s without) and
# oversubscribe the cores when two processes run
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1} OPENBLAS_NUM_THREADS=${OPENBLAS_NUM_THREADS:-1} \
    MKL_NUM_THREADS=${MKL_NUM_THREADS:-1}
exec .venv/bin/python -m pytest -n 2 --dist loadgroup "$@"
