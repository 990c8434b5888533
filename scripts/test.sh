#!/usr/bin/env bash
# The one command that installs what the tests need (project-local) and runs every test.
# Release mode: the renderer tests are compute-heavy.
set -euo pipefail
cd "$(dirname "$0")/.."
./scripts/setup-test-env.sh
# Form first (seconds): formatting and lints are part of passing.
cargo fmt --check
cargo clippy --release --all-targets --locked -- -D warnings
cargo test --release --locked "$@"
