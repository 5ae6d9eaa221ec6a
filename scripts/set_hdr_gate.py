#!/usr/bin/env python3
"""Set the HDR gate of an estimator weights file: where E may brighten a pixel.

E is multiplied by ``smoothstep(gate_lo, gate_hi, max_rgb(I))`` (``rvr_addon.estimate.unet``): only
pixels near clipping get HDR radiance. The gate is part of the weights' config (their JSON header);
this rewrites it in ``estimator.pt`` and ``estimator.json`` (the same header), weights untouched.
Re-export the ONNX file afterwards (``scripts/export_onnx.py``); the weights' hash changes, so
caches made with the old gate are recomputed.

Usage: .venv/bin/python scripts/set_hdr_gate.py rvr_addon/estimate/weights/estimator.pt 0.96 0.996
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("weights", type=Path, help="estimator.pt written by `rvr train`")
    parser.add_argument("gate_lo", type=float, help="sRGB max-channel value where the gate starts (0..1)")
    parser.add_argument("gate_hi", type=float, help="sRGB max-channel value where it reaches 1 (0..1)")
    args = parser.parse_args()
    import torch

    from rvr_addon.estimate.train import WEIGHTS_FORMAT
    from rvr_addon.estimate.unet import EstimatorConfig

    obj = torch.load(args.weights, map_location="cpu", weights_only=True)
    if not isinstance(obj, dict) or obj.get("format") != WEIGHTS_FORMAT:
        sys.exit(f"{args.weights} is not an estimator weights file ({WEIGHTS_FORMAT})")
    header = json.loads(obj["header"])
    old = (header["config"].get("gate_lo"), header["config"].get("gate_hi"))
    header["config"].update(gate_lo=args.gate_lo, gate_hi=args.gate_hi)
    EstimatorConfig.from_dict(header["config"])  # validates the pair
    obj["header"] = json.dumps(header)
    tmp = args.weights.with_suffix(".pt.tmp")
    torch.save(obj, tmp)
    tmp.replace(args.weights)
    beside = args.weights.with_suffix(".json")
    if beside.is_file():
        beside.write_text(json.dumps(header, indent=1))
    print(f"{args.weights}: gate {old[0]}..{old[1]} -> {args.gate_lo}..{args.gate_hi}"
          + (f" (and {beside.name})" if beside.is_file() else ""))


if __name__ == "__main__":
    main()
