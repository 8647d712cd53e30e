#!/usr/bin/env bash
# One entry point for a fresh machine: installs what vdp needs, then runs a job.
#   bash deploy/bootstrap.sh run    -> sets up and runs the main job
#   bash deploy/bootstrap.sh test   -> sets up and runs the whole test suite
# Extra arguments go to the job (pytest or vdp).
set -euo pipefail
cd "$(dirname "$0")/.."

mode=${1:-run}
shift || true

# Debian packages: iproute2 for the network-namespace end-to-end tests, chromium for the
# dashboard's browser test (Debian's build: a browser that downloads itself cannot here).
if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    missing=()
    command -v ip >/dev/null 2>&1 || missing+=(iproute2)
    command -v unshare >/dev/null 2>&1 || missing+=(util-linux)
    [ "$mode" = test ] && ! command -v chromium >/dev/null 2>&1 && missing+=(chromium)
    if ((${#missing[@]})); then
        apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" \
            || echo "bootstrap: could not install ${missing[*]}; the tests that need them will skip" >&2
    fi
fi

PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
    "$PY" -m venv .venv
fi
stamp=.venv/.vdp-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
    .venv/bin/python -m pip install -q --upgrade pip >/dev/null 2>&1 || true
    .venv/bin/python -m pip install -q -e ".[test,opendbc,parquet,fleet,bench]"
    touch "$stamp"
fi
export PATH="$PWD/.venv/bin:$PATH"

# the vcan test runs where the kernel has the module (it skips with its reason elsewhere)
if [ "$mode" = test ] && [ "$(id -u)" = 0 ]; then modprobe vcan 2>/dev/null || true; fi

case "$mode" in
    test)
        # form first: lint and format are part of the test command (pyproject's [tool.ruff])
        .venv/bin/ruff check . && .venv/bin/ruff format --check . || exit 1
        # the compiled filter steps once, before any test (a fresh checkout compiles them: ~15 s)
        .venv/bin/python -c "from vdp.core import warm; warm.warm(); from vdp.io import scan; scan.warm()"
        # on both cores (pytest-xdist), a test file per worker: a file's module fixtures are built
        # once; VDP_TEST_WORKERS=0 runs it in one process
        exec .venv/bin/python -m pytest -n "${VDP_TEST_WORKERS:-2}" --dist loadfile "$@" ;;
    run)  exec .venv/bin/vdp serve --simulate --loop "$@" ;;
    simulate) exec .venv/bin/vdp simulate "$@" ;;
    *) echo "usage: bash deploy/bootstrap.sh run|test|simulate [args...]" >&2; exit 2 ;;
esac
