#!/usr/bin/env python3
"""Export the shipped estimator and AF-Net weights to ONNX, next to them:
``rvr_addon/estimate/weights/estimator.onnx``, ``rvr_addon/afnet/weights/afnet_unit.onnx`` and
``afnet_head.onnx`` (what the Blender extension runs without torch, :mod:`rvr_addon.onnxrun`).
Run it after retraining either network and commit the files with the weights;
``tests/engine/test_onnx.py`` fails while a file and its weights drift apart.

Needs torch and onnx (both in .venv: scripts/setup.sh).

Usage: .venv/bin/python scripts/export_onnx.py [--output-dir DIR]   (prints the files written)
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rvr_addon.onnx_export import export_all  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output-dir", type=Path, default=None,
                        help="write the files here instead of next to the weights")
    args = parser.parse_args()
    for path in export_all(args.output_dir):
        print(f"{path} ({path.stat().st_size / 1e6:.2f} MB)")


if __name__ == "__main__":
    main()
