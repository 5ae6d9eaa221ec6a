#!/usr/bin/env bash
# Download the Python wheels the Blender extension bundles (runtime dependencies Blender does
# not ship: numpy it does) into ./wheels, for Linux x86_64 and Blender's Python 3.11.
# blender_manifest.toml lists exactly these files; change both together.
#
# OpenEXR 3.5.3 and imageio-ffmpeg 0.8.1 publish only manylinux_2_28 wheels (glibc >= 2.28, as
# Blender 4.2+ itself needs), opencv only manylinux2014: pip is given both platform tags.
#
# Usage: scripts/fetch_wheels.sh   (from anywhere; PIP=... to choose the pip)
set -euo pipefail
cd "$(dirname "$0")/.."
PIP=${PIP:-pip}
if ! command -v "$PIP" >/dev/null 2>&1; then
    PIP=".venv/bin/pip"
fi
mkdir -p wheels
"$PIP" download --only-binary=:all: --no-deps --python-version 3.11 \
    --platform manylinux2014_x86_64 --platform manylinux_2_28_x86_64 \
    -d wheels \
    opencv-contrib-python-headless==4.11.0.86 \
    OpenEXR==3.5.3 \
    imageio-ffmpeg==0.8.1 \
    tqdm==4.70.1

# every wheel the manifest names must now be in ./wheels
missing=0
for wheel in $(sed -n 's|^ *"\./\(wheels/[^"]*\.whl\)",\{0,1\}$|\1|p' blender_manifest.toml); do
    if [ ! -f "$wheel" ]; then
        echo "missing $wheel (named in blender_manifest.toml)" >&2
        missing=1
    fi
done
exit $missing
