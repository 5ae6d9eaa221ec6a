#!/usr/bin/env bash
# Create .venv (Python 3.11) with every pinned dependency and the project in editable mode.
# Usage: scripts/setup.sh            (idempotent; re-run after pulling)
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null || PY=python3
"$PY" - <<'PYCHECK'
import sys
if sys.version_info[:2] != (3, 11):
    sys.exit(f"RVR-LAAF needs Python 3.11 (bpy 5.0.1 is built for it); found {sys.version.split()[0]}. "
             "Set PYTHON=/path/to/python3.11")
PYCHECK
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install --quiet --upgrade "pip>=24"
.venv/bin/python -m pip install --quiet -r requirements.txt -c constraints.txt
# mediapipe without its metadata's dependencies (a second OpenCV, jax, ...): requirements-nodeps.txt
.venv/bin/python -m pip install --quiet --no-deps -r requirements-nodeps.txt
.venv/bin/python -m pip install --quiet --no-deps --no-build-isolation -e .
# the wheels the Blender extension zip bundles (scripts/build_extension.py; the install test uses them)
PIP=.venv/bin/pip scripts/fetch_wheels.sh >/dev/null \
  || echo "rvr-laaf: could not download the extension's wheels; run scripts/fetch_wheels.sh before building the zip" >&2
# espeak-ng (Debian package; the harness' "conversation" script speaks with it). Best effort:
# installed with apt-get when we are root and it is missing; the harness names the fix otherwise.
# Tested with Debian 12's 1.51+dfsg-10+deb12u2 (the version is taken from the distribution).
if ! command -v espeak-ng >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq espeak-ng) \
      || echo "rvr-laaf: could not install espeak-ng; 'sintel_eval generate --script conversation' needs it" >&2
  else
    echo "rvr-laaf: espeak-ng is missing; for 'sintel_eval generate --script conversation' run: sudo apt-get install espeak-ng" >&2
  fi
fi
.venv/bin/python -c "import bpy, cv2, torch, OpenEXR, imageio_ffmpeg, mediapipe, onnxruntime, onnx; cv2.ximgproc; print('rvr-laaf: .venv ready (Blender', bpy.app.version_string + ', torch', torch.__version__ + ')')"
