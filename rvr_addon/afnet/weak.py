"""Weak AF-Net labels from the AI-assist detectors on real clips (kept apart from ground truth).

Runs a LAAF preset (``action``, ``conversation``, ``faces``, ``salient``) on a clip with its
disparity (an ``rvr estimate`` cache or maps) and writes what it decided as a focus annotation
file (:mod:`.annotations`) with every record flagged ``weak: true`` and sourced
``weak:<preset>``: an NFT record per automatic NFT (its box at its frame), and region records
(``nft: false``) every ``every`` frames for the tracked box of the target in focus while the
tracker holds it. ``rvr train-afnet --annotations weak.json`` trains on them at
``--weak-weight``; no evaluation reads them as ground truth.

    python -m rvr_addon.afnet.weak CLIP (--cache CACHE | --depth MAPS) --preset action -o weak.json
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .annotations import AnnotatedClip, Annotation, write_annotations


def weak_labels(clip: str | Path, preset: str, cache: str | Path | None = None, depth: str | Path | None = None,
                every: int = 5, window_s: float = 2.0, progress: bool = False) -> AnnotatedClip:
    """Run ``preset`` on ``clip`` and return its decisions as weak records (module docstring)."""
    from ..laaf.lookahead import AutofocusJob, AutofocusSettings

    if preset == "learned":
        raise ValueError("weak labels come from the AI-assist presets, not from AF-Net itself (preset learned)")
    job = AutofocusJob(AutofocusSettings(input=Path(clip), cache=Path(cache) if cache else None,
                                         depth=Path(depth) if depth else None, preset=preset, window_s=window_s))
    result = job.run(progress=progress)
    source = f"weak:{preset}"
    records: list[Annotation] = []
    for i, nft in enumerate(result.nfts):
        if i > 0:  # the first target is the initial focus, not an NFT
            records.append(Annotation(nft.t + result.start, tuple(nft.box), source, True, True))
        boxes = result.boxes[i] if i < len(result.boxes) else {}
        end = result.nfts[i + 1].t if i + 1 < len(result.nfts) else len(result.focus)
        for k, (box, ok) in sorted(boxes.items()):
            if ok and nft.t <= k < end and (k - nft.t) % every == 0 and (k != nft.t or i == 0) \
                    and box[2] >= 1 and box[3] >= 1:
                records.append(Annotation(k + result.start, tuple(box), f"{source}:tracked", False, True))
    depth_src = Path(cache) if cache else (Path(depth) if depth else None)
    return AnnotatedClip(Path(clip), records, weak=True, depth=depth_src)


def main(argv: list[str] | None = None) -> int:
    """``python -m rvr_addon.afnet.weak``: write weak labels of one or more clips to a JSON file."""
    import logging

    from ..errors import RvrError

    p = argparse.ArgumentParser(prog="python -m rvr_addon.afnet.weak", description=__doc__.split("\n\n")[0])
    p.add_argument("clip", type=Path, help="video or image sequence")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--cache", type=Path, help="rvr estimate cache of the clip")
    src.add_argument("--depth", type=Path, help="disparity maps of the clip")
    p.add_argument("--preset", required=True, choices=("action", "conversation", "faces", "salient"))
    p.add_argument("--every", type=int, default=5, help="a region record every N frames (default 5)")
    p.add_argument("-o", "--output", type=Path, required=True, help="annotation file to write (.json)")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        clip = weak_labels(args.clip, args.preset, args.cache, args.depth, max(1, args.every), progress=True)
        write_annotations(args.output, [clip])
    except RvrError as ex:
        print(f"error: {ex}", file=sys.stderr)
        return 2
    n = sum(r.nft for r in clip.records)
    print(f"wrote {args.output}: {n} weak NFTs, {len(clip.records) - n} weak region records")
    return 0


if __name__ == "__main__":
    sys.exit(main())
