"""docs/demo.jpg, the README's picture: frames of the demo as ``input | refocused | depth``.

    .venv/bin/rvr refocus --demo && .venv/bin/python scripts/demo_picture.py [--frames 40 110 170]

Reads what ``rvr refocus --demo`` left in out/demo/ (the video, its focus file, the work folder).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> int:
    from rvr_addon.refocus.preview import write_contact_sheet

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--demo", type=Path, default=ROOT / "out" / "demo")
    ap.add_argument("--frames", type=int, nargs="+", default=[40, 110, 170])
    ap.add_argument("-o", "--output", type=Path, default=ROOT / "docs" / "demo.jpg")
    args = ap.parse_args()
    video = args.demo / "bikes_refocused.mp4"
    work = sorted((args.demo / "rvr_cache").glob("bikes-*"))
    if not video.is_file() or not work:
        raise SystemExit(f"run `rvr refocus --demo` first ({video} or its work folder is missing)")
    clips = sorted(work[-1].glob("clip_*.mp4"))
    from rvr_addon.refocus.demo import demo_clip

    clip = clips[-1] if clips else demo_clip()
    write_contact_sheet(args.output, clip, work[-1] / "cache", video, args.demo / "bikes_refocused.focus.json",
                        width=1200, frames=args.frames, order=("input", "refocused", "depth"), quality=80)
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
