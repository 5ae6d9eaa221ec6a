"""Scoring a focus file against a hand annotation of a real clip (issue 23, "Evaluation on real clips").

The annotation is JSON::

    {"fps": 25.0,
     "turns": [{"start_s": 4.84, "end_s": 5.52, "box": [x, y, w, h]}, ...],   # the speaker's region, native px
     "cuts": [120, ...]}                                                       # optional: first frame of each new shot

The existing speaker annotation of the interview (``tests/data/interview_speakers.json``:
``stretches`` of ``speaker`` left/right of a split 1280x720 frame) is accepted too and
converted by :func:`turns_from_sides`.

Per frame the focus file's ``focus_on`` block names the governing target and its tracked box;
"on the speaker" below means that box's centre lies inside the turn's box (a frame without a
tracked box is not on anyone). Frames are 0-based clip frames; a time ``t`` is frame
``round(t * fps)`` and a turn covers frames ``[start, end)``.

Figures (:func:`score_focus`):

- ``lead_frames`` per turn that changes speaker (its box differs from the previous turn's): the
  first frame at or after the previous turn's end whose governing box centre lies in the new
  speaker's box, minus the turn's start frame (negative = lead: on the speaker before the voice;
  None = never on the speaker before the turn ended). ``lead_landed_frames``: the same, but the
  frame must also not be part of a pull (the pull has landed).
- ``turns_led`` / ``turns_changed``: turns with lead <= 0 out of the turns that change speaker.
- ``speaking_share``: the share of the turns' frames whose governing box centre is in the box.
- ``spurious_per_min``: governing-target changes more than 1 s away from every turn start and
  every cut (the annotation's cuts; the focus file's own when the annotation names none), per
  minute of the scored frames.
- ``pulls_across_cuts``: pulls (runs of ``pull`` frames to one target) that contain an
  annotated cut and the frame before it.
- Off-screen speech (annotation key ``offscreen``: ``[{"start_s", "end_s"}]``, a voice no face
  on screen utters): ``offscreen_changes``, governing-target changes inside those segments
  (those within 1 s before the next turn starts excepted: a look-ahead pull to the next
  speaker), and ``offscreen_moved_share``, the share of their frames whose governing box centre
  is no longer in the region (the annotation's panel boxes, else the turn boxes) it was in at
  the segment's start: focus pulled to a silent face. Absent (None) without such segments.
  A segment's lead exception does not reach over a cut: no pull may lead across one.
- Edited clips (annotation key ``shots``: ``[{"first": frame, "box": [x, y, w, h]}]``, the first
  frame of each shot and the box of the subject it shows; ``cuts`` the first frames after the
  first shot): ``cut_lag_frames`` per annotated cut, the first frame at or after the cut whose
  governing box centre lies in the new shot's subject box, minus the cut frame (None: never in
  that shot); ``cuts_on_subject``: cuts with lag 0 (focus set at once on the new shot's
  subject); ``cut_lag_frames_max``: the largest lag, a cut never on its subject counting as its
  shot's length. With ``shots`` the off-screen regions are per shot: a frame is "home" when its
  governing box centre lies in the box of the shot it belongs to, and ``offscreen_moved_share``
  counts the frames whose home-ness differs from the segment's first frame. Absent (None)
  without ``shots``.
"""
from __future__ import annotations

import json
from pathlib import Path

SIDES_SIZE = (1280, 720)


def turns_from_sides(doc: dict, width: int = SIDES_SIZE[0], height: int = SIDES_SIZE[1]) -> dict:
    """An annotation of ``stretches`` with ``speaker`` 'left'/'right' (halves of a split-screen
    ``width`` x ``height`` frame) as the ``turns`` annotation; ``fps`` and ``cuts`` are kept."""
    half = width // 2
    boxes = {"left": [0, 0, half, height], "right": [half, 0, width - half, height]}
    turns = []
    for s in doc["stretches"]:
        if s["speaker"] not in boxes:
            raise ValueError(f"stretch speaker {s['speaker']!r}: expected 'left' or 'right'")
        turns.append({"start_s": float(s["start_s"]), "end_s": float(s["end_s"]), "box": list(boxes[s["speaker"]]),
                      "speaker": s["speaker"]})
    out = {"fps": float(doc["fps"]), "turns": turns}
    if "cuts" in doc:
        out["cuts"] = [int(c) for c in doc["cuts"]]
    if "clip" in doc:
        out["clip"] = doc["clip"]
    return out


def normalise_annotation(doc: dict) -> dict:
    """The ``turns`` annotation of either accepted format (ValueError naming what is missing)."""
    if "turns" not in doc and "stretches" in doc:
        doc = turns_from_sides(doc)
    if "turns" not in doc:
        raise ValueError("the annotation has no 'turns' (nor 'stretches' + 'sides')")
    if not doc.get("fps"):
        raise ValueError("the annotation has no 'fps'")
    for t in doc["turns"]:
        if len(t.get("box") or []) != 4 or not float(t["end_s"]) > float(t["start_s"]):
            raise ValueError(f"turn {t}: needs start_s < end_s and a box [x, y, w, h]")
    return doc


def load_annotation(path: str | Path) -> dict:
    """Read and normalise an annotation file."""
    return normalise_annotation(json.loads(Path(path).read_text()))


def _inside(box, region) -> bool:
    if box is None:
        return False
    cx, cy = box[0] + box[2] / 2.0, box[1] + box[3] / 2.0
    x, y, w, h = region
    return x <= cx < x + w and y <= cy < y + h


def score_focus(focus_doc: dict, annotation: dict) -> dict:
    """Score a focus document (``rvr autofocus``'s JSON) against an annotation (module docstring)."""
    ann = normalise_annotation(annotation)
    fps = float(ann["fps"])
    on = focus_doc["focus_on"]
    start = int(on.get("start", 0))
    target, boxes, states = on["target"], on["box"], on["state"]
    n = len(target)
    stop = start + n

    def frame(t: float) -> int:
        return int(round(t * fps))

    turns = sorted(ann["turns"], key=lambda t: float(t["start_s"]))
    per_turn, speak, speak_on = [], 0, 0
    for i, t in enumerate(turns):
        a, b = frame(float(t["start_s"])), frame(float(t["end_s"]))
        box = [float(v) for v in t["box"]]
        on_f = [k for k in range(max(a, start), min(b, stop)) if _inside(boxes[k - start], box)]
        speak += max(0, min(b, stop) - max(a, start))
        speak_on += len(on_f)
        row = {"start": a, "end": b, "box": box, "on_frames": len(on_f), "changes_speaker": False,
               "lead_frames": None, "lead_landed_frames": None}
        if "speaker" in t:
            row["speaker"] = t["speaker"]
        prev = turns[i - 1] if i else None
        if prev is not None and [float(v) for v in prev["box"]] != box:
            row["changes_speaker"] = True
            lo = max(frame(float(prev["end_s"])), start)
            for k in range(lo, min(b, stop)):
                if _inside(boxes[k - start], box):
                    if row["lead_frames"] is None:
                        row["lead_frames"] = k - a
                    if states[k - start] != "pull":
                        row["lead_landed_frames"] = k - a
                        break
        per_turn.append(row)
    changed = [r for r in per_turn if r["changes_speaker"]]
    leads = [r["lead_frames"] for r in changed if r["lead_frames"] is not None]

    ann_cuts = [int(c) for c in ann.get("cuts", [])]
    cuts = ann_cuts if "cuts" in ann else [int(c) for c in focus_doc.get("cuts", [])]
    near = [r["start"] for r in per_turn] + cuts
    changes = [k for k in range(start + 1, stop) if target[k - start] != target[k - 1 - start]]
    spurious = [k for k in changes if all(abs(k - c) > fps for c in near)]
    minutes = n / fps / 60.0

    regions = [p["box"] for p in ann.get("panels", [])] or [t["box"] for t in turns]
    shots = sorted(({"first": int(sh["first"]), "box": [float(v) for v in sh["box"]]} for sh in ann.get("shots", [])),
                   key=lambda sh: sh["first"])

    def shot_of(k: int) -> dict | None:
        return next((sh for sh in reversed(shots) if sh["first"] <= k), None)

    def region_of(k: int):
        box = boxes[k - start]
        if shots:  # per shot: on the subject of the shot that frame k belongs to, or not
            sh = shot_of(k)
            return sh is not None and _inside(box, sh["box"])
        return next((i for i, r in enumerate(regions) if _inside(box, r)), None)

    off_changes, off_frames, off_moved = 0, 0, 0
    for seg in ann.get("offscreen", []):
        a, b = max(frame(float(seg["start_s"])), start), min(frame(float(seg["end_s"])), stop)
        if b <= a:
            continue
        nxt = [r["start"] for r in per_turn if r["start"] >= a]
        lead_from = (min(nxt) - int(round(fps))) if nxt else b
        if nxt and any(a < c <= min(nxt) for c in ann_cuts):
            lead_from = b  # the next turn is in another shot: no pull may lead to it across the cut
        off_changes += sum(1 for k in changes if a < k < min(b, lead_from))
        home = region_of(a)
        for k in range(a, min(b, lead_from)):
            off_frames += 1
            off_moved += region_of(k) != home
    has_off = bool(ann.get("offscreen"))

    cut_lags: list[int | None] = []
    cut_lag_cost: list[int] = []
    if shots:
        for c in ann_cuts:
            sh = shot_of(c)
            if sh is None or sh["first"] != c or not start < c < stop:
                continue
            end = next((o["first"] for o in shots if o["first"] > c), stop)
            lag = next((k - c for k in range(c, min(end, stop)) if _inside(boxes[k - start], sh["box"])), None)
            cut_lags.append(lag)
            cut_lag_cost.append(lag if lag is not None else min(end, stop) - c)

    crossing = 0
    for c in ann_cuts:
        if start < c < stop and states[c - start] == "pull" and states[c - 1 - start] == "pull" \
                and target[c - start] == target[c - 1 - start]:
            crossing += 1

    return {
        "fps": fps,
        "frames": n,
        "turns": per_turn,
        "turns_changed": len(changed),
        "turns_led": sum(1 for v in leads if v <= 0),
        "turns_led_landed": sum(1 for r in changed if r["lead_landed_frames"] is not None
                                and r["lead_landed_frames"] <= 0),
        "turns_missed": len(changed) - len(leads),
        "lead_frames_mean": round(sum(leads) / len(leads), 3) if leads else None,
        "speaking_frames": speak,
        "speaking_share": round(speak_on / speak, 4) if speak else None,
        "target_changes": len(changes),
        "spurious_changes": spurious,
        "spurious_per_min": round(len(spurious) / minutes, 3) if minutes > 0 else None,
        "cuts_annotated": len(ann_cuts),
        "pulls_across_cuts": crossing,
        "offscreen_changes": off_changes if has_off else None,
        "offscreen_moved_share": (round(off_moved / off_frames, 4) if off_frames else 0.0) if has_off else None,
        "cut_lag_frames": cut_lags if shots else None,
        "cuts_on_subject": sum(1 for v in cut_lags if v == 0) if shots else None,
        "cut_lag_frames_max": (max(cut_lag_cost) if cut_lag_cost else 0) if shots else None,
    }


FIGURES = ("speaking_share", "turns_led", "turns_changed", "turns_led_landed", "turns_missed", "lead_frames_mean",
           "spurious_per_min", "pulls_across_cuts", "offscreen_changes", "offscreen_moved_share", "cuts_annotated",
           "cuts_on_subject", "cut_lag_frames_max")


def evaluate_real(clip: Path, annotation: Path, output: Path, presets, *, cache=None, depth=None, causal_too=False,
                  window_s: float = 2.0, pull=None, progress: bool = True, **settings) -> dict:
    """Run the autofocus engine on ``clip`` per preset (look-ahead; with ``causal_too`` causal as
    well), score each run against ``annotation`` and write ``output``/summary.json (flat
    ``focus.real.<clip>.<preset>[.causal].<figure>`` keys), details.json (per-turn rows) and the
    focus files under ``output``/focus. Returns the summary."""
    from .focusfile import focus_document, write_focus_file
    from .lookahead import AutofocusJob, AutofocusSettings
    from .puller import PullSettings

    ann = load_annotation(annotation)
    name = Path(clip).stem
    output = Path(output)
    (output / "focus").mkdir(parents=True, exist_ok=True)
    summary, details = {}, {}
    for preset in presets:
        for causal in ((False, True) if causal_too else (False,)):
            s = AutofocusSettings(input=Path(clip), cache=cache, depth=depth, preset=preset, window_s=window_s,
                                  causal=causal, pull=pull if pull is not None else PullSettings(), **settings)
            result = AutofocusJob(s).run(progress=progress)
            tag = preset + (".causal" if causal else "")
            write_focus_file(output / "focus" / f"{name}.{tag}.json", result)
            score = score_focus(focus_document(result), ann)
            auto = result.settings.get("auto")
            if auto:
                score["auto_chose"] = auto.get("chose")
            details[f"{name}.{tag}"] = score
            key = f"focus.real.{name}.{preset}" + (".causal" if causal else "")
            for f in FIGURES:
                summary[f"{key}.{f}"] = score[f]
            if auto:
                summary[f"{key}.auto_chose"] = auto.get("chose")
    (output / "summary.json").write_text(json.dumps(summary, indent=1, sort_keys=True))
    (output / "details.json").write_text(json.dumps(details, indent=1))
    return summary
