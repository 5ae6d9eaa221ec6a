#!/usr/bin/env bash
# Download the Python wheels the Blender extension bundles (runtime dependencies Blender does
# not ship: numpy it does) into ./wheels, for Linux x86_64 and Blender's Python 3.11.
# blender_manifest.toml lists exactly these files; change both together.
#
# mediapipe 0.10.14 (the people depth cue, rvr_addon/depth/people.py) is fetched into
# wheels/upstream/ and repacked by scripts/slim_wheel.py into wheels/ without the models the cue
# never loads (35.7 -> 14.2 MB, build tag 1); its dependencies absl-py, attrs, flatbuffers and
# protobuf 4.25.9 are bundled as they are (matplotlib, jax, sounddevice and opencv-contrib-python,
# which its metadata also names, are not: the cue does not need them).
#
# onnxruntime 1.31.1 (the estimator and AF-Net as ONNX, no torch in Blender: rvr_addon/onnxrun.py) is
# repacked the same way without its C API library and tools (23.8 -> 11.6 MB, build tag 1); its
# dependencies numpy (Blender's), flatbuffers and protobuf are bundled already (packaging and sympy,
# which its metadata also names, are never imported by the inference API). webrtcvad-wheels 2.0.14.post1
# is WebRTC's voice activity detector of the Conversation preset (rvr_addon/laaf/audio.py).
#
# OpenEXR 3.5.3 and imageio-ffmpeg 0.8.1 publish only manylinux_2_28 wheels (glibc >= 2.28, as
# Blender 4.2+ itself needs), opencv only manylinux2014: pip is given both platform tags.
#
# --with-torch also fetches the wheels of the "full" zip (build_extension.py --with-torch),
# exactly the files scripts/torch_wheels.txt lists: the torch 2.13.0 CPU wheel is copied from
# $TORCH_WHEEL_DIR (default /opt/wheels) when it is there, else downloaded as exactly
# torch==2.13.0+cpu from the PyTorch CPU index (never an unpinned torch: that is a multi-GB
# CUDA build); its dependencies come from PyPI, pinned by their file names.
#
# Usage: scripts/fetch_wheels.sh [--with-torch]   (from anywhere; PIP=... to choose the pip)
set -euo pipefail
cd "$(dirname "$0")/.."
WITH_TORCH=0
for arg in "$@"; do
    case "$arg" in
        --with-torch) WITH_TORCH=1 ;;
        *) echo "usage: scripts/fetch_wheels.sh [--with-torch]" >&2; exit 2 ;;
    esac
done
PIP=${PIP:-pip}
if ! command -v "$PIP" >/dev/null 2>&1; then
    PIP=".venv/bin/pip"
fi
TORCH_WHEEL_DIR=${TORCH_WHEEL_DIR:-/opt/wheels}
TORCH_INDEX=https://download.pytorch.org/whl/cpu
mkdir -p wheels
download() {  # pinned requirements -> ./wheels, binary Linux x86_64 CPython 3.11 wheels only
    "$PIP" download --only-binary=:all: --no-deps --python-version 3.11 \
        --platform manylinux2014_x86_64 --platform manylinux_2_28_x86_64 \
        -d "${WHEEL_DEST:-wheels}" "$@"
}
download \
    opencv-contrib-python-headless==4.11.0.86 \
    OpenEXR==3.5.3 \
    imageio-ffmpeg==0.8.1 \
    tqdm==4.70.1 \
    absl-py==2.5.1 \
    attrs==26.1.0 \
    flatbuffers==25.12.19 \
    protobuf==4.25.9 \
    webrtcvad-wheels==2.0.14.post1
MEDIAPIPE=mediapipe-0.10.14-cp311-cp311-manylinux_2_17_x86_64.manylinux2014_x86_64.whl
if [ ! -f "wheels/${MEDIAPIPE/-cp311-/-1-cp311-}" ]; then
    [ -f "wheels/upstream/$MEDIAPIPE" ] || WHEEL_DEST=wheels/upstream download mediapipe==0.10.14
    "${PYTHON:-python3}" scripts/slim_wheel.py "wheels/upstream/$MEDIAPIPE" wheels >/dev/null
fi
ONNXRUNTIME=onnxruntime-1.31.1-cp311-cp311-manylinux_2_28_x86_64.whl
if [ ! -f "wheels/${ONNXRUNTIME/-cp311-/-1-cp311-}" ]; then
    [ -f "wheels/upstream/$ONNXRUNTIME" ] || WHEEL_DEST=wheels/upstream download onnxruntime==1.31.1
    "${PYTHON:-python3}" scripts/slim_wheel.py "wheels/upstream/$ONNXRUNTIME" wheels >/dev/null
fi

# every wheel the manifest names must now be in ./wheels
missing=0
for wheel in $(sed -n 's|^ *"\./\(wheels/[^"]*\.whl\)",\{0,1\}$|\1|p' blender_manifest.toml); do
    if [ ! -f "$wheel" ]; then
        echo "missing $wheel (named in blender_manifest.toml)" >&2
        missing=1
    fi
done
[ "$WITH_TORCH" = 1 ] || exit $missing

# --with-torch: the files scripts/torch_wheels.txt names (name-version-...whl -> name==version)
torch_list=$(grep -v '^ *\(#\|$\)' scripts/torch_wheels.txt)
pins=()
for wheel in $torch_list; do
    name=${wheel%%-*}
    rest=${wheel#*-}
    version=${rest%%-*}
    [ -f "wheels/$wheel" ] && continue
    if [ "$name" = torch ]; then
        if [ -f "$TORCH_WHEEL_DIR/$wheel" ]; then
            cp "$TORCH_WHEEL_DIR/$wheel" wheels/
        else  # untested here (only PyPI is reachable on the development machine)
            "$PIP" download --only-binary=:all: --no-deps --python-version 3.11 \
                --platform manylinux_2_28_x86_64 --index-url "$TORCH_INDEX" \
                -d wheels "torch==$version"
        fi
    else
        pins+=("$name==$version")
    fi
done
if [ ${#pins[@]} -gt 0 ]; then
    download "${pins[@]}"
fi
for wheel in $torch_list; do
    if [ ! -f "wheels/$wheel" ]; then
        echo "missing wheels/$wheel (named in scripts/torch_wheels.txt)" >&2
        missing=1
    fi
done
exit $missing
