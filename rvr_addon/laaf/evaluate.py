"""``rvr eval-focus``: LAAF against ground-truth New Focus Targets (paper section 6.2).

Harness clips (``sintel_eval/DATASET.md``) carry exact disparity and the events a focus puller
would react to. For each clip and preset, LAAF runs twice on the ground-truth disparity
(look-ahead with the default 2 s window, and causal) and is compared with the ground truth:

- **Ground-truth focus track** implied by the ground-truth NFTs: the main subject
  (``manifest.scene.main``) is in focus from frame 0; each ground-truth NFT whose subject is
  not the one already in focus (an event on the subject in focus moves no focal plane, so it
  is no New Focus Target) starts a pull to that subject, scheduled by the *same* puller
  (pull_frames, lead_frames, profile) as ours; between pulls the focus follows the subject's
  exact disparity at its focus point (``subjects[name].per_frame[k].disparity``).
- **mean |delta d|** (paper: Delta d = D(x, y) - D(x^, y^), averaged over all frames): the mean
  over all frames of |f(t) - f_gt(t)| in disparity units (DESIGN units: px of blur radius at
  aperture 1 at the native width), f our per-frame focus disparity.
- **mean |delta t|** (paper: Delta t = t - t^, averaged over NFTs): predicted NFTs are taken at
  the frame a system could act on them, ``max(t, known_at)`` (look-ahead: t; causal: the frame
  the evidence arrived), excluding the initial focus target. Each ground-truth NFT is matched
  to at most one prediction, greedily by smallest |t - t^| within ``max_dt`` frames (default:
  one second of frames); an unmatched ground-truth NFT counts as a miss with |delta t| =
  ``max_dt``. Unmatched predictions are false NFTs (counted; they cost in |delta d|).
- Per clip and overall (pooled: |delta d| over all frames of all clips, |delta t| over all
  ground-truth NFTs). The headline ``focus.<preset>.*`` keys pool the clips the preset is made
  for (action: enter and start-moving; conversation: conversation); ``.all`` pools every clip
  (the random script, whose crossing extras have no ground-truth event, counts there).
- Preset ``learned`` (AF-Net, paper section 5.3, Table 2) is made for every kind of clip, so
  its headline keys pool all clips; compare them with the presets' ``.all`` keys (the same
  clips). A clip without ground-truth NFTs adds frames to |delta d| and nothing to |delta t|.
  Its weights come from ``afnet_weights`` (checked once, before any clip runs). ``learned``
  takes an NFT's region from the speaker where someone speaks (``afnet_speaker``);
  ``learned-map`` is the same network with every region from AF-Net's own map (the paper's).
"""
from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError
from .lookahead import AutofocusJob, AutofocusResult, AutofocusSettings
from .presets import EVAL_PRESETS, VARIANTS  # noqa: F401 - re-exported: rvr_addon.laaf.evaluate.EVAL_PRESETS
from .puller import PullSettings, PullTarget, compose_track

log = logging.getLogger(__name__)

PRESET_SCRIPTS = {"action": ("enter", "start-moving"), "conversation": ("conversation",),
                  "faces": ("conversation",), "salient": ("enter", "start-moving"),
                  "learned": ("enter", "start-moving", "conversation", "random"),
                  "learned-map": ("enter", "start-moving", "conversation", "random")}


@dataclass
class GroundTruth:
    """focus: (n,) ground-truth focus track; nfts: [(frame, subject)] that move the focus."""

    focus: np.ndarray
    nfts: list[tuple[int, str]]
    events: list[dict]


@dataclass
class ClipScore:
    """Scores of one run: per-frame |delta d|, per-GT-NFT |delta t| (misses at max_dt)."""

    clip: str
    script: str
    preset: str
    causal: bool
    dd: np.ndarray
    dt: list[float]
    misses: int
    false_nfts: int
    focus: np.ndarray
    nft_times: list[int]
    extra: dict = field(default_factory=dict)

    @property
    def mean_dd(self) -> float:
        return float(np.mean(self.dd))

    @property
    def mean_dt(self) -> float | None:
        return float(np.mean(self.dt)) if self.dt else None


def harness_clips(dataset: str | Path) -> list[Path]:
    """Complete harness clip folders under ``dataset`` (or the folder itself), sorted by name.

    A clip counts when its manifest's status is complete (or every frame has its done marker).
    Raises InputError when none is found."""
    root = Path(dataset)
    if not root.is_dir():
        raise InputError(f"dataset folder '{root}' not found; give a folder of harness clips "
                         "(`python -m sintel_eval generate -o DIR/clip`)")
    cands = [root] if (root / "manifest.json").is_file() else sorted(p for p in root.iterdir() if p.is_dir())
    clips = []
    for c in cands:
        try:
            m = json.loads((c / "manifest.json").read_text())
        except (OSError, ValueError):
            continue
        if not str(m.get("format", "")).startswith("rvr-laaf-harness/"):
            continue
        n = int(m.get("config", {}).get("frames") or m.get("frames") or 0)
        done = (c / "done").is_dir() and len(list((c / "done").glob("frame_*.json"))) >= n > 0
        if m.get("status", {}).get("complete") or done:
            clips.append(c)
        else:
            log.warning("skipping %s: not complete yet", c)
    if not clips:
        raise InputError(f"no complete harness clip in '{root}'")
    return clips


def manifest_fps(manifest: dict) -> float:
    """A harness clip's frame rate (frames/s; 24 when its manifest does not say)."""
    return float(manifest.get("config", {}).get("fps") or manifest.get("fps") or 24)


def ground_truth(manifest: dict, settings: PullSettings) -> GroundTruth:
    """The ground-truth focus track and NFTs of a clip (module docstring)."""
    n = int(manifest.get("config", {}).get("frames") or manifest["frames"])
    subjects = manifest["subjects"]

    def level(name: str) -> np.ndarray:
        return np.array([p["disparity"] for p in subjects[name]["per_frame"]][:n], np.float64)

    main = manifest["scene"]["main"]
    current = main
    targets = [PullTarget(0, level(main))]
    nfts = []
    for ev in sorted(manifest.get("events", []), key=lambda e: e["index"]):
        if ev["subject"] == current or ev["subject"] not in subjects:
            continue
        current = ev["subject"]
        t = int(ev["index"])
        if targets and targets[-1].t == t:
            targets.pop()
            nfts.pop()
        targets.append(PullTarget(t, level(current)))
        nfts.append((t, current))
    focus = compose_track(targets, n, settings, fps=manifest_fps(manifest)).focus
    return GroundTruth(focus, nfts, manifest.get("events", []))


def match_nfts(pred: list[int], gt: list[int], max_dt: int) -> tuple[list[float], int, int]:
    """Greedy one-to-one matching by smallest |t - t^| within max_dt.

    Returns (|delta t| per ground-truth NFT, misses at max_dt, false predictions)."""
    pairs = sorted((abs(p - g), i, j) for i, p in enumerate(pred) for j, g in enumerate(gt) if abs(p - g) <= max_dt)
    used_p, used_g, dt = set(), {}, {}
    for d, i, j in pairs:
        if i in used_p or j in used_g:
            continue
        used_p.add(i)
        used_g[j] = i
        dt[j] = float(d)
    out = [dt.get(j, float(max_dt)) for j in range(len(gt))]
    return out, len(gt) - len(dt), len(pred) - len(used_p)


def clip_input(folder: Path) -> Path:
    """The clip's input: input.mp4 (with its speech audio) or the input/ PNG folder."""
    mp4 = folder / "input.mp4"
    return mp4 if mp4.is_file() else folder / "input"


def score_run(folder: Path, manifest: dict, preset: str, causal: bool, pull: PullSettings,
              window_s: float = 2.0, max_dt: int | None = None, afnet_weights: Path | None = None,
              afnet_threshold: float | None = None) -> tuple[ClipScore, AutofocusResult]:
    """Run LAAF on one clip (ground-truth disparity) and score it."""
    fps = manifest_fps(manifest)
    base, overrides = VARIANTS.get(preset, (preset, {}))
    settings = AutofocusSettings(input=clip_input(folder), depth=folder / "gt" / "disparity", preset=base,
                                 window_s=window_s, causal=causal, pull=pull, fps=fps, afnet_weights=afnet_weights,
                                 afnet_threshold=afnet_threshold, **overrides)
    result = AutofocusJob(settings).run(progress=False)
    gt = ground_truth(manifest, pull)
    n = min(len(gt.focus), len(result.focus))
    dd = np.abs(result.focus[:n].astype(np.float64) - gt.focus[:n])
    pred = [nf.act_at for nf in result.nfts[1:]]
    max_dt = int(round(fps)) if max_dt is None else max_dt
    dt, misses, false = match_nfts(pred, [t for t, _ in gt.nfts], max_dt)
    script = str(manifest.get("config", {}).get("script", "?"))
    return ClipScore(folder.name, script, preset, causal, dd, dt, misses, false, result.focus[:n], pred,
                     {"gt_focus": gt.focus[:n], "gt_nfts": gt.nfts,
                      "fallback": result.settings.get("fallback")}), result


def _pool(scores: list[ClipScore]) -> dict:
    dd = np.concatenate([s.dd for s in scores]) if scores else np.zeros(0)
    dt = [d for s in scores for d in s.dt]
    return {"mean_dd": float(dd.mean()) if dd.size else None, "mean_dt_frames": float(np.mean(dt)) if dt else None,
            "misses": sum(s.misses for s in scores), "false_nfts": sum(s.false_nfts for s in scores),
            "gt_nfts": len(dt), "clips": len(scores)}


def _plot(path: Path, clip: str, runs: dict[str, tuple[ClipScore, ClipScore]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(runs), 1, figsize=(8, 2.8 * len(runs)), squeeze=False)
    for ax, (preset, (la, ca)) in zip(axes[:, 0], runs.items()):
        t = np.arange(len(la.focus))
        ax.plot(t, la.extra["gt_focus"], "k-", lw=2, label="ground truth")
        ax.plot(t, la.focus, "C0-", label=f"look-ahead (|dd| {la.mean_dd:.2f})")
        ax.plot(t, ca.focus, "C3--", label=f"causal (|dd| {ca.mean_dd:.2f})")
        for g, _ in la.extra["gt_nfts"]:
            ax.axvline(g, color="k", ls=":", lw=1)
        for p in la.nft_times:
            ax.plot([p], [np.interp(p, t, la.focus)], "C0v")
        for p in ca.nft_times:
            ax.plot([p], [np.interp(p, t, ca.focus)], "C3v")
        ax.set_title(f"{clip}: preset {preset}" + (f" ({la.extra['fallback']})" if la.extra.get("fallback") else ""),
                     fontsize=9)
        ax.set_xlabel("frame")
        ax.set_ylabel("focus disparity")
        ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def evaluate(dataset: str | Path, out: str | Path, presets: list[str], pull: PullSettings | None = None,
             window_s: float = 2.0, progress: bool = True, afnet_weights: Path | None = None,
             afnet_threshold: float | None = None) -> dict:
    """Evaluate every preset, look-ahead and causal, on every clip; write the report folder
    (summary.json, report.md, one plot per clip). Returns the summary dict.

    Raises InputError before any clip runs when preset ``learned`` is asked for and its AF-Net
    weights (``afnet_weights``, default the shipped ones) are missing."""
    from tqdm import tqdm

    if any(VARIANTS.get(p, (p,))[0] == "learned" for p in presets):
        from ..afnet.infer import load_afnet

        load_afnet(afnet_weights)  # fail now, naming the path and the command that makes it
    pull = pull or PullSettings()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    clips = harness_clips(dataset)
    scores: list[ClipScore] = []
    bar = tqdm(total=len(clips) * len(presets) * 2, unit="run", disable=not progress, desc="eval-focus")
    for folder in clips:
        manifest = json.loads((folder / "manifest.json").read_text())
        runs = {}
        for preset in presets:
            pair = []
            for causal in (False, True):
                score, _ = score_run(folder, manifest, preset, causal, pull, window_s,
                                     afnet_weights=afnet_weights, afnet_threshold=afnet_threshold)
                scores.append(score)
                pair.append(score)
                bar.update(1)
            runs[preset] = tuple(pair)
        _plot(out / f"{folder.name}.png", folder.name, runs)
    bar.close()
    summary: dict = {}
    for preset in presets:
        for causal in (False, True):
            mode = ".causal" if causal else ""
            mine = [s for s in scores if s.preset == preset and s.causal == causal]
            made_for = [s for s in mine if s.script in PRESET_SCRIPTS.get(preset, ())]
            for key, group in (("", made_for), (".all", mine)):
                pooled = _pool(group)
                for metric in ("mean_dt_frames", "mean_dd", "misses", "false_nfts", "gt_nfts", "clips"):
                    if pooled[metric] is not None:
                        summary[f"focus.{preset}{key}{mode}.{metric}"] = round(float(pooled[metric]), 4)
            for s in mine:
                summary[f"focus.{preset}{mode}.{s.clip}.mean_dd"] = round(s.mean_dd, 4)
                if s.mean_dt is not None:
                    summary[f"focus.{preset}{mode}.{s.clip}.mean_dt_frames"] = round(s.mean_dt, 4)
    (out / "summary.json").write_text(json.dumps(summary, indent=1, sort_keys=True))
    (out / "report.md").write_text(_markdown(scores, summary, presets, pull, window_s))
    return summary


def _fmt(v) -> str:
    return "-" if v is None else f"{v:.2f}"


def _frames_or_default(frames: int | None, default: str) -> str:
    return default if frames is None else f"{frames} frames"


def _markdown(scores: list[ClipScore], summary: dict, presets: list[str], pull: PullSettings, window_s: float) -> str:
    lines = ["# LAAF evaluation (`rvr eval-focus`)", "",
             f"Ground-truth disparity; look-ahead window {window_s:g} s vs causal; pull "
             f"{_frames_or_default(pull.pull_frames, '0.4 s')} ({pull.profile}), landing "
             f"{_frames_or_default(pull.lead_frames, '0.2 s')} before the NFT. Definitions: "
             "`rvr_addon/laaf/evaluate.py` (mean |dd| over all frames in disparity units; mean |dt| over "
             "ground-truth NFTs in frames, misses counted at 1 s).", "",
             "| clip | script | preset | GT NFTs | look-ahead mean abs dt | look-ahead mean abs dd | "
             "causal mean abs dt | causal mean abs dd | look-ahead NFTs (act at) | misses / false |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for s in [s for s in scores if not s.causal]:
        c = next(x for x in scores if x.causal and x.clip == s.clip and x.preset == s.preset)
        lines.append(f"| {s.clip} | {s.script} | {s.preset} | {[t for t, _ in s.extra['gt_nfts']]} | "
                     f"{_fmt(s.mean_dt)} | {_fmt(s.mean_dd)} | {_fmt(c.mean_dt)} | {_fmt(c.mean_dd)} | "
                     f"{s.nft_times} | {s.misses} / {s.false_nfts} |")
    lines += ["", "## Overall (clips each preset is made for)", "",
              "| preset | look-ahead mean abs dt | look-ahead mean abs dd | causal mean abs dt | causal mean abs dd |",
              "|---|---|---|---|---|"]
    for p in presets:
        g = summary.get
        lines.append(f"| {p} | {_fmt(g(f'focus.{p}.mean_dt_frames'))} | {_fmt(g(f'focus.{p}.mean_dd'))} | "
                     f"{_fmt(g(f'focus.{p}.causal.mean_dt_frames'))} | {_fmt(g(f'focus.{p}.causal.mean_dd'))} |")
    lines += ["", "## All clips (the same clips for every preset; `learned` = AF-Net)", "",
              "| preset | clips | look-ahead mean abs dt | look-ahead mean abs dd | misses / false | "
              "causal mean abs dt | causal mean abs dd |", "|---|---|---|---|---|---|---|"]
    for p in presets:
        g = summary.get
        lines.append(f"| {p} | {int(g(f'focus.{p}.all.clips', 0))} | {_fmt(g(f'focus.{p}.all.mean_dt_frames'))} | "
                     f"{_fmt(g(f'focus.{p}.all.mean_dd'))} | {int(g(f'focus.{p}.all.misses', 0))} / "
                     f"{int(g(f'focus.{p}.all.false_nfts', 0))} | {_fmt(g(f'focus.{p}.all.causal.mean_dt_frames'))} | "
                     f"{_fmt(g(f'focus.{p}.all.causal.mean_dd'))} |")
    lines += ["", "Plots: `<clip>.png` (black: ground truth, blue: look-ahead, red dashed: causal; "
              "dotted lines: ground-truth NFTs; triangles: predicted NFTs).", ""]
    return "\n".join(lines)
