#!/usr/bin/env python3
"""Repack the mediapipe and onnxruntime wheels for the Blender extension without what we never load.

onnxruntime 1.31.1 (the ONNX networks without torch, rvr_addon/onnxrun.py): without its C API
library, the transformer/quantization tools and the backend test API (:data:`DROP_PREFIXES`).

mediapipe 0.10.14's wheel (35.7 MB) carries the models of every legacy solution; the people
depth cue (rvr_addon/depth/people.py) runs selfie segmentation, full-range face detection and the
refined face mesh only. This writes a copy of the wheel without the other ``*.tflite`` files (pose,
hands, palms, irises, holistic, objectron, the unrefined face mesh): every Python module and graph
file stays, so ``import mediapipe`` and the solutions we use work as before, and only building an
unused solution would fail (its model file missing). The copy gets the wheel build tag ``1`` (its
version stays 0.10.14) and a RECORD that lists what it holds, with fresh hashes.

Usage: python3 scripts/slim_wheel.py UPSTREAM.whl OUT_DIR   (prints the written wheel's path)
       Deterministic (same input, same bytes); standard library only.
"""
from __future__ import annotations

import base64
import csv
import hashlib
import io
import sys
import zipfile
from pathlib import Path

BUILD_TAG = "1"
KEEP_MODELS = {
    "mediapipe/modules/selfie_segmentation/selfie_segmentation.tflite",
    "mediapipe/modules/selfie_segmentation/selfie_segmentation_landscape.tflite",
    "mediapipe/modules/face_detection/face_detection_full_range_sparse.tflite",
    "mediapipe/modules/face_detection/face_detection_short_range.tflite",  # face mesh's own detector
    "mediapipe/modules/face_landmark/face_landmark_with_attention.tflite",  # refine_landmarks=True
}
"""The only model files kept (every other ``*.tflite`` is dropped)."""


def slim_name(upstream: str) -> str:
    """``name-version-py-abi-plat.whl`` -> ``name-version-1-py-abi-plat.whl``."""
    parts = upstream[:-4].split("-")
    if len(parts) != 5:
        raise SystemExit(f"{upstream}: expected a wheel name without a build tag (name-version-py-abi-platform.whl)")
    return "-".join(parts[:2] + [BUILD_TAG] + parts[2:]) + ".whl"


DROP_PREFIXES: dict[str, tuple[str, ...]] = {
    "onnxruntime": (
        "onnxruntime/capi/libonnxruntime.so",  # the C API library; the Python module links its own copy
        "onnxruntime/transformers/", "onnxruntime/quantization/", "onnxruntime/tools/", "onnxruntime/datasets/",
        "onnxruntime/backend/",  # the ONNX backend test API (imports onnx)
    ),
}
"""Per distribution, members dropped from its wheel (what ``import onnxruntime`` and an
``InferenceSession`` on the CPU never load: 23.8 -> about 12 MB)."""


def keep(name: str, package: str = "mediapipe") -> bool:
    """Whether a member of the upstream wheel of ``package`` goes into the slim one."""
    if package == "mediapipe":
        return not name.endswith(".tflite") or name in KEEP_MODELS
    if name.endswith(".dist-info/entry_points.txt"):
        return False  # console scripts of dropped modules; Blender installs no scripts anyway
    return not name.startswith(DROP_PREFIXES.get(package, ()))


def _record_hash(data: bytes) -> str:
    return "sha256=" + base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()


def slim(upstream: Path, out_dir: Path) -> Path:
    """Write the slim copy of ``upstream`` into ``out_dir``; returns its path."""
    out = out_dir / slim_name(upstream.name)
    with zipfile.ZipFile(upstream) as src:
        package = upstream.name.split("-")[0].lower()
        infos = [i for i in src.infolist() if keep(i.filename, package)]
        records = [i for i in infos if i.filename.endswith(".dist-info/RECORD")]
        wheel_files = [i for i in infos if i.filename.endswith(".dist-info/WHEEL")]
        if len(records) != 1 or len(wheel_files) != 1:
            raise SystemExit(f"{upstream}: not a wheel (one .dist-info/RECORD and WHEEL expected)")
        record_name, wheel_name = records[0].filename, wheel_files[0].filename
        rows = []
        tmp = out.with_suffix(".part")
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as dst:
            for info in infos:
                if info.filename == record_name:
                    continue
                data = src.read(info)
                if info.filename == wheel_name:
                    lines = [ln for ln in data.decode().splitlines() if not ln.startswith("Build:")]
                    data = ("\n".join(lines).rstrip("\n") + f"\nBuild: {BUILD_TAG}\n").encode()
                new = zipfile.ZipInfo(info.filename, date_time=info.date_time)
                new.external_attr, new.compress_type = info.external_attr, zipfile.ZIP_DEFLATED
                dst.writestr(new, data, compresslevel=9)
                if not info.is_dir():
                    rows.append([info.filename, _record_hash(data), str(len(data))])
            rows.append([record_name, "", ""])
            text = io.StringIO()
            csv.writer(text, lineterminator="\n").writerows(rows)
            new = zipfile.ZipInfo(record_name, date_time=records[0].date_time)
            new.external_attr, new.compress_type = records[0].external_attr, zipfile.ZIP_DEFLATED
            dst.writestr(new, text.getvalue().encode(), compresslevel=9)
    tmp.replace(out)
    return out


def main() -> None:
    if len(sys.argv) != 3:
        raise SystemExit("usage: python3 scripts/slim_wheel.py UPSTREAM.whl OUT_DIR")
    upstream, out_dir = Path(sys.argv[1]), Path(sys.argv[2])
    if not upstream.is_file():
        raise SystemExit(f"{upstream} not found; scripts/fetch_wheels.sh downloads it")
    out_dir.mkdir(parents=True, exist_ok=True)
    print(slim(upstream, out_dir))


if __name__ == "__main__":
    main()
