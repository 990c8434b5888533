#!/usr/bin/env bash
# The one command that installs what the tests need (project-local) and runs every test.
# Release mode: the renderer tests are compute-heavy.
set -euo pipefail
cd "$(dirname "$0")/.."
./scripts/setup-test-env.sh
cargo test --release --locked "$@"
