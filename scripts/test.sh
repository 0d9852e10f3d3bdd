#!/usr/bin/env bash
# Set up everything the tests need on a fresh Debian machine and run them:
# Debian's linuxcnc-uspace (the LinuxCNC interpreter used as an oracle), a virtual
# environment with sdit-path and its test extras, then pytest.
set -euo pipefail
cd "$(dirname "$0")/.."

as_root() { if [ "$(id -u)" -eq 0 ]; then "$@"; else sudo "$@"; fi; }

if ! dpkg -s linuxcnc-uspace >/dev/null 2>&1; then
    echo "== installing Debian's linuxcnc-uspace (LinuxCNC interpreter for the oracle tests)"
    as_root apt-get update -qq
    DEBIAN_FRONTEND=noninteractive as_root apt-get install -y -qq linuxcnc-uspace >/dev/null
fi

PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
    echo "== creating .venv"
    "$PY" -m venv .venv
fi
echo "== installing sdit-path and test dependencies"
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e '.[test]'

echo "== running the tests"
exec .venv/bin/python -m pytest "$@"
