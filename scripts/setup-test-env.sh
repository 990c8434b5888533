#!/usr/bin/env bash
# Installs what the test suite needs into project-local folders (nothing system-wide):
#   .venv/   Python with the oracle packages from scripts/requirements-test.txt, including
#            the onnxruntime wheel whose onnxruntime/capi/libonnxruntime.so.* drbokeh finds there
#   .tools/exiftool/   ExifTool (Debian's libimage-exiftool-perl), for the GDepth tests
#   .tools/heif/pug.heic   an iPhone portrait photo with its depth image (from pillow-heif's
#            source distribution on PyPI), for tests/heif.rs
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
    # uv (from PyPI) installs the requirements: 44-54 s against pip's 122 s from an empty cache
    # on 2 cores, most of it PyTorch's CUDA wheels (measured 2026-11-29). pip remains the
    # fallback where uv cannot be had or fails.
    if .venv/bin/python -m pip install --quiet --disable-pip-version-check uv==0.9.30 &&
        .venv/bin/uv pip install --quiet --native-tls --python .venv/bin/python -r scripts/requirements-test.txt; then
        :
    else
        echo "uv failed: installing with pip" >&2
        .venv/bin/python -m pip install --quiet --disable-pip-version-check -r scripts/requirements-test.txt
    fi
    echo "$want" > "$stamp"
fi
# PyMatting compiles its numba kernels when first imported (~40 s of one core) and caches them
# beside its sources: done here, where scripts/test.sh runs it beside the compiler, rather than
# inside tests/matting_pymatting.rs. Seconds once cached.
.venv/bin/python -c "import pymatting"

# Debian packages, unpacked without root: `deb_unpack DIR PACKAGE...` downloads them with
# `apt-get download` and unpacks each with `dpkg -x` into DIR.
deb_unpack() {
    local dir=$1
    shift
    local tmp
    tmp=$(mktemp -d)
    chmod a+rwx "$tmp" # apt's download user, when run as root
    (cd "$tmp" && apt-get download -qq "$@")
    mkdir -p "$dir"
    for deb in "$tmp"/*.deb; do
        dpkg -x "$deb" "$dir"
    done
    rm -rf "$tmp"
}

# ExifTool, the independent reader and writer of GDepth XMP (tests/embedded_depth.rs): Debian's
# libimage-exiftool-perl (pure Perl, runs with the system perl), downloaded with
# `apt-get download` (no root) and unpacked with `dpkg -x` into .tools/exiftool/. Where apt is
# not available, say so and go on: those tests then name what is missing (or use
# $DRBOKEH_EXIFTOOL, an exiftool executable of your own).
exiftool_dir=.tools/exiftool
if [ ! -f "$exiftool_dir/usr/bin/exiftool" ]; then
    if command -v apt-get >/dev/null && command -v dpkg >/dev/null; then
        deb_unpack "$exiftool_dir" libimage-exiftool-perl
        echo "ExifTool $(perl -I "$exiftool_dir/usr/share/perl5" "$exiftool_dir/usr/bin/exiftool" -ver) unpacked into $exiftool_dir"
    else
        echo "warning: apt-get/dpkg not found: ExifTool not installed ($exiftool_dir); tests/embedded_depth.rs's ExifTool tests need it or \$DRBOKEH_EXIFTOOL" >&2
    fi
fi

# A HEIC written by an iPhone (a portrait photo with a uniform-disparity depth image and an HDR
# gain map): pillow-heif's test image, taken from its source distribution on PyPI (pinned and
# checked), the real-camera file tests/heif.rs reads.
heif_dir=.tools/heif
pug_sha=1ddce96766efbfa0f6bdf634bdab26bdeff831393df8d67f4cdc7b7a7afebc67
if [ "$(sha256sum "$heif_dir/pug.heic" 2>/dev/null | cut -d' ' -f1)" != "$pug_sha" ]; then
    tmp=$(mktemp -d)
    .venv/bin/python -m pip download --quiet --disable-pip-version-check --no-deps --no-binary :all: \
        --dest "$tmp" pillow-heif==1.8.1
    mkdir -p "$heif_dir"
    tar -xzf "$tmp"/pillow_heif-1.8.1.tar.gz -C "$tmp" pillow_heif-1.8.1/tests/images/heif_other/pug.heic
    cp "$tmp"/pillow_heif-1.8.1/tests/images/heif_other/pug.heic "$heif_dir/pug.heic"
    rm -rf "$tmp"
    echo "$pug_sha  $heif_dir/pug.heic" | sha256sum --check --quiet
    echo "pillow-heif's iPhone HEIC (pug.heic) copied into $heif_dir"
fi

# Chromium's headless shell, the browser tests/view.rs drives `drbokeh view`'s page with
# (Debian's chromium-headless-shell, with the libraries it needs that a server image lacks),
# unpacked into .tools/chromium/ and run with LD_LIBRARY_PATH pointing there ($DRBOKEH_CHROMIUM:
# a headless Chromium of your own).
chromium_dir=.tools/chromium
if [ ! -x "$chromium_dir/usr/lib/chromium/chromium-headless-shell" ] && [ -z "${DRBOKEH_CHROMIUM:-}" ]; then
    if command -v apt-get >/dev/null && command -v dpkg >/dev/null; then
        deb_unpack "$chromium_dir" chromium-headless-shell chromium-common libopenh264-7 libdouble-conversion3 libopus0 \
            libharfbuzz-subset0 libxnvctrl0 libpulse0 libflac12 libminizip1 libogg0 libsndfile1 libasyncns0 libvorbis0a \
            libvorbisenc2 libmpg123-0 libmp3lame0
        echo "Chromium's headless shell unpacked into $chromium_dir"
    else
        echo "warning: apt-get/dpkg not found: Chromium not installed ($chromium_dir); tests/view.rs's page test needs it or \$DRBOKEH_CHROMIUM" >&2
    fi
fi
