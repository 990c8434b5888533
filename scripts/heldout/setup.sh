#!/usr/bin/env bash
# Creates .venv-heldout (gitignored) with the pinned renderer and libraries that
# scripts/heldout/make_scenes.py needs, from PyPI only.
set -euo pipefail
cd "$(dirname "$0")/../.."
python3 -m venv .venv-heldout
.venv-heldout/bin/pip install --quiet --upgrade pip
.venv-heldout/bin/pip install --quiet -r scripts/heldout/requirements.txt
.venv-heldout/bin/python -c "import mitsuba as mi; mi.set_variant('scalar_rgb'); print('mitsuba', mi.MI_VERSION, 'scalar_rgb ok')"
