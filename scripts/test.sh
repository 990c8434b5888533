#!/usr/bin/env bash
# The one command that installs what the tests need (project-local) and runs every test.
# Release mode: the renderer tests are compute-heavy.
set -euo pipefail
cd "$(dirname "$0")/.."
# The installs (downloads and unpacking: 2-3 minutes from nothing) run in the background while
# the compiler works; nothing is compiled from them. Their output is shown once they end.
setup_log=$(mktemp)
./scripts/setup-test-env.sh >"$setup_log" 2>&1 &
setup_pid=$!
trap 'kill "$setup_pid" 2>/dev/null || true; rm -f "$setup_log"' EXIT
# Form first (seconds): formatting and lints are part of passing.
cargo fmt --all --check
# Every generated table (README's headline, docs/) matches the reports it is made from.
python3 scripts/readme_bench_tables.py --check
cargo clippy --workspace --release --all-targets --locked -- -D warnings
# --workspace: the features of drbokeh's dependencies resolved as for the Python extension
# (python/ has no Rust tests), so `pip install ./python` below reuses this build of drbokeh
# instead of compiling it again with other features (1m42s -> 6s on 2 cores).
cargo test --release --locked --workspace --no-run "$@"
setup_rc=0
wait "$setup_pid" || setup_rc=$?
cat "$setup_log"
if [ "$setup_rc" -ne 0 ]; then
    echo "scripts/setup-test-env.sh failed (exit $setup_rc): its output is above" >&2
    exit "$setup_rc"
fi
cargo test --release --locked --workspace "$@"
# The Python package (python/): built into .venv from this checkout with the command README
# gives (maturin, release; it reuses the build above), then its tests against the binary the
# Rust tests built. Skipped when arguments narrow the Rust tests to a subset.
if [ $# -eq 0 ]; then
    PATH="$PWD/.venv/bin:$PATH" .venv/bin/python -m pip install --quiet --disable-pip-version-check --no-build-isolation ./python
    .venv/bin/python -m pytest -q python/tests
fi
