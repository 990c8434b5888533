#!/usr/bin/env bash
# Installs what the test suite needs into project-local folders (nothing system-wide):
#   .venv/   Python with the oracle packages from scripts/requirements-test.txt, including
#            the onnxruntime wheel whose onnxruntime/capi/libonnxruntime.so.* drbokeh finds there
#   .tools/exiftool/   ExifTool (Debian's libimage-exiftool-perl), for the GDepth tests
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

# ExifTool, the independent reader and writer of GDepth XMP (tests/embedded_depth.rs): Debian's
# libimage-exiftool-perl (pure Perl, runs with the system perl), downloaded with
# `apt-get download` (no root) and unpacked with `dpkg -x` into .tools/exiftool/. Where apt is
# not available, say so and go on: those tests then name what is missing (or use
# $DRBOKEH_EXIFTOOL, an exiftool executable of your own).
exiftool_dir=.tools/exiftool
if [ ! -f "$exiftool_dir/usr/bin/exiftool" ]; then
    if command -v apt-get >/dev/null && command -v dpkg >/dev/null; then
        tmp=$(mktemp -d)
        chmod a+rwx "$tmp" # apt's download user, when run as root
        (cd "$tmp" && apt-get download -qq libimage-exiftool-perl)
        mkdir -p "$exiftool_dir"
        dpkg -x "$tmp"/libimage-exiftool-perl_*.deb "$exiftool_dir"
        rm -rf "$tmp"
        echo "ExifTool $(perl -I "$exiftool_dir/usr/share/perl5" "$exiftool_dir/usr/bin/exiftool" -ver) unpacked into $exiftool_dir"
    else
        echo "warning: apt-get/dpkg not found: ExifTool not installed ($exiftool_dir); tests/embedded_depth.rs's ExifTool tests need it or \$DRBOKEH_EXIFTOOL" >&2
    fi
fi
