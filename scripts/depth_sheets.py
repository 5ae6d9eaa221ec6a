"""Contact sheets of the depth system on real clips: input | D (network alone) | D (auto) | refocused.

```
.venv/bin/python scripts/depth_sheets.py [CLIP ...] [--frame K] [--weights W] [-o docs/depth]
```

Default clips: every video in ../shared/data/clips. For each, frames 0..K+10 run through the
same depth system as ``rvr estimate --depth-method auto`` (rvr_addon.depth.system), frame K is
shown; D is coloured near = red, far = blue (the 2-98 % range of each map); the refocused frame
is rendered by our renderer focused on the nearest person's face (the frame's centre without
people) at aperture scale 3. Writes OUT/contact_sheet.jpg (all clips; with --each also
OUT/<clip>.jpg per clip).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def colour(d: np.ndarray, near_is_low: bool = True) -> np.ndarray:
    """D -> BGR uint8 (turbo), near = red."""
    import cv2

    lo, hi = np.percentile(d, [2, 98])
    a = np.clip((d - lo) / max(hi - lo, 1e-9), 0, 1)
    if near_is_low:
        a = 1.0 - a
    return cv2.applyColorMap((a * 255).astype(np.uint8), cv2.COLORMAP_TURBO)


def sheet(clip: Path, frame_index: int, weights: Path | None) -> np.ndarray:
    """One row (BGR uint8): input | network D | auto D | refocused, and a label."""
    import cv2

    from rvr_addon.depth.people import PeopleDetector
    from rvr_addon.depth.system import DepthStream, plan_depth
    from rvr_addon.estimate.infer import Estimator, default_weights, load_estimator
    from rvr_addon.io.video import iter_frames, probe_clip
    from rvr_addon.render.fast import render_frame

    info = probe_clip(clip)
    k = min(frame_index, info.frame_count - 1)
    stop = min(info.frame_count, k + 11)
    est = Estimator(load_estimator(weights or default_weights()))
    plan = plan_depth("auto", lambda: iter_frames(clip, start=0, stop=stop))
    stream = DepthStream(plan, (info.width, info.height), est)
    for i, (frame, d, e, fused) in enumerate(stream.frames(iter_frames(clip, start=0, stop=stop))):
        if i == k:
            break
    stream.close()
    d_net, _ = est(frame)
    with PeopleDetector() as people:
        persons = people(frame).persons
    if persons:
        x0, y0, x1, y1 = persons[0].face_box
        cx, cy = int((x0 + x1) / 2), int((y0 + y1) / 2)
    else:
        cx, cy = info.width // 2, info.height // 2
    focus = float(np.median(d[max(cy - 2, 0):cy + 3, max(cx - 2, 0):cx + 3]))
    out = render_frame(frame, d, focus, 3.0, e)
    refocused = cv2.cvtColor((np.clip(out, 0, 1) * 255 + 0.5).astype(np.uint8), cv2.COLOR_RGB2BGR)
    row = np.hstack([frame[..., ::-1], colour(d_net), colour(d), refocused])
    scale = 1600 / row.shape[1]
    row = cv2.resize(row, (1600, int(row.shape[0] * scale)), interpolation=cv2.INTER_AREA)
    label = f"{clip.name} frame {k}: {' + '.join(fused.cues)}"
    cv2.putText(row, label, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 2, cv2.LINE_AA)
    return row


def main(argv: list[str] | None = None) -> int:
    import cv2

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("clips", nargs="*", type=Path)
    ap.add_argument("--frame", type=int, default=12)
    ap.add_argument("--weights", type=Path)
    ap.add_argument("-o", "--output", type=Path, default=ROOT / "docs" / "depth")
    ap.add_argument("--each", action="store_true", help="also write one picture per clip")
    a = ap.parse_args(argv)
    clips = a.clips or sorted((ROOT.parent / "shared" / "data" / "clips").glob("*.*"))
    a.output.mkdir(parents=True, exist_ok=True)
    rows = []
    for clip in clips:
        row = sheet(clip, a.frame, a.weights)
        if a.each:
            cv2.imwrite(str(a.output / f"{clip.stem}.jpg"), row, [cv2.IMWRITE_JPEG_QUALITY, 85])
        rows.append(row)
        print(f"{clip.name}: done")
    if rows:
        cv2.imwrite(str(a.output / "contact_sheet.jpg"), np.vstack(rows), [cv2.IMWRITE_JPEG_QUALITY, 80])
        print(f"wrote {a.output / 'contact_sheet.jpg'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
