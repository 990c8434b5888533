#!/usr/bin/env bash
# Installs what the test suite needs into project-local folders (nothing system-wide):
#   .venv/   Python with the oracle packages from scripts/requirements-test.txt, including
#            the onnxruntime wheel whose onnxruntime/capi/libonnxruntime.so.* drbokeh finds there
# Safe to run repeatedly; it only installs what is missing.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
py=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
    "$py" -m venv .venv
fi
stamp=.venv/.requirements.sha
want=$(sha256sum scripts/requirements-test.txt | cut -d' ' -f1)
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
    .venv/bin/python -m pip install --quiet --disable-pip-version-check -r scripts/requirements-test.txt
    echo "$want" > "$stamp"
fi
