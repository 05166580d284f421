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
# pip's own WARNING/ERROR lines are shown; the build backend's notices (setuptools prints
# a page per editable install) only when the step fails, with everything else
pip_step() {
  local log
  log=$(mktemp)
  if .venv/bin/python -m pip "$@" >"$log" 2>&1; then
    grep -E '^(WARNING|ERROR|DEPRECATION):' "$log" >&2 || true
    rm -f "$log"
  else
    cat "$log" >&2
    rm -f "$log"
    echo "bootstrap: pip $* failed (output above)" >&2
    return 1
  fi
}
stamp=.venv/.bootstrap-$(sha256sum requirements.lock pyproject.toml | sha256sum | cut -c1-16)
if [ ! -f "$stamp" ]; then
  echo "bootstrap: creating .venv"
  [ -x .venv/bin/python ] || "$PY" -m venv .venv
  pip_step install -q --upgrade "pip>=23"
  pip_step install -q -r requirements.lock
  pip_step install -q --no-deps -e .
  rm -f .venv/.bootstrap-*; touch "$stamp"
fi
