#!/usr/bin/env bash
# Installs everything the project needs on a fresh Debian machine: a C compiler
# (apt, only if missing) and the Python environment in .venv/ from requirements.lock.
# Idempotent: a second run only checks.
set -euo pipefail
cd "$(dirname "$0")"
if ! command -v gcc >/dev/null 2>&1; then
  echo "bootstrap: installing gcc (apt)"
  if [ "$(id -u)" = 0 ]; then apt-get update -qq && apt-get install -y -qq gcc libc6-dev >/dev/null
  else sudo apt-get update -qq && sudo apt-get install -y -qq gcc libc6-dev >/dev/null; fi
fi
# headless browser for the report-rendering test (tests/test_report.py)
if ! command -v chromium >/dev/null 2>&1; then
  echo "bootstrap: installing chromium (apt)"
  if [ "$(id -u)" = 0 ]; then apt-get update -qq && apt-get install -y -qq chromium >/dev/null
  else sudo apt-get update -qq && sudo apt-get install -y -qq chromium >/dev/null; fi
fi
PY=${PYTHON:-python3}
stamp=.venv/.bootstrap-$(sha256sum requirements.lock pyproject.toml | sha256sum | cut -c1-16)
if [ ! -f "$stamp" ]; then
  echo "bootstrap: creating .venv"
  [ -x .venv/bin/python ] || "$PY" -m venv .venv
  .venv/bin/python -m pip install -q --upgrade "pip>=23" >/dev/null
  .venv/bin/python -m pip install -q -r requirements.lock
  .venv/bin/python -m pip install -q --no-deps -e .
  rm -f .venv/.bootstrap-*; touch "$stamp"
fi
