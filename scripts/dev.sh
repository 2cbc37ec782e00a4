#!/usr/bin/env bash
# Set up everything handful needs on a fresh Debian machine, then run one job:
#   bash scripts/dev.sh demo    # the demo service (server + workers + dashboard)
#   bash scripts/dev.sh test    # the whole test suite
#   bash scripts/dev.sh setup   # only set up
set -euo pipefail
cd "$(dirname "$0")/.."
job="${1:-demo}"; shift || true

need_apt=()
command -v chromium >/dev/null 2>&1 || need_apt+=(chromium)
ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1 || need_apt+=(postgresql)  # tests/api/test_postgres.py
if [ "${#need_apt[@]}" -gt 0 ] && [ "$job" != "demo" ]; then
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need_apt[@]}" >/dev/null
fi

PY="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
# torch first and pinned: the CPU build on this disk (an unpinned torch pulls CUDA).
if ! .venv/bin/python -c "import torch" >/dev/null 2>&1; then
  .venv/bin/pip install -q --upgrade pip
  .venv/bin/pip install -q "torch==2.13.0"
fi
.venv/bin/pip install -q -e ".[dev]"

case "$job" in
  setup) ;;
  demo) exec .venv/bin/handful demo "$@" ;;
  test)
    .venv/bin/ruff check app tests benchmarks
    .venv/bin/ruff format --check app tests benchmarks
    .venv/bin/mypy  # app/service, app/api, app/policy.py ([tool.mypy] in pyproject.toml)
    # pytest exits 5 when it collects nothing: that is a failure here too.
    exec .venv/bin/python -m pytest "$@" ;;
  *) echo "unknown job '$job' (use demo, test or setup)" >&2; exit 2 ;;
esac
