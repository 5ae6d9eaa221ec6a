"""Artifact ablations against Cycles' ground truth (paper section 6.3; issue 3).

    python -m sintel_eval ablate DATASET -o REPORT [--variants a,b] [--force] [--max-frames N]

For every clip of DATASET (see sintel_eval/DATASET.md) and every ground-truth focus track
(``dof/<track>/``), every variant of :data:`.variants.VARIANTS` renders the clip frame by
frame; each output is scored against Cycles' shallow-DOF render by :class:`.scoring.RunScorer`
and kept as an 8-bit PNG in a scratch folder for the comparison images and videos. Then
:mod:`.report` writes the REPORT folder.

Bad input. A clip that is incomplete (a missing or stale done marker, a missing or truncated
file) or whose files turn out corrupt while it is read (an unreadable EXR or PNG, NaNs) is
skipped with a logged reason naming the file; the other clips go on, and the report lists the
skipped clips (``ablation.clips_skipped`` in summary.json, reasons in README.md). If no clip
is left, the run fails with all the reasons. A folder that is not a dataset fails at once.

The report is written into a hidden temp folder beside REPORT and renamed into place at the
end: an interrupted run leaves no half report. An existing REPORT is replaced only with
``--force``, and only if it is an earlier report (holds summary.json) or empty.
"""
from __future__ import annotations

import argparse
import logging
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from rvr_addon.color import to_uint8
from rvr_addon.errors import InputError, OutputError
from rvr_addon.io.paths import replace_folder, temp_sibling

from .cli_args import positive_int
from .metrics import display_srgb, evaluation_flow
from .reader import ClipReader, find_clips
from .scoring import RunScorer, ScoreSettings
from .variants import VARIANTS, Variant, select

log = logging.getLogger(__name__)


@dataclass
class RunResult:
    """The scores of one variant on one track of one clip.

    metrics: the run's figures (:meth:`.scoring.RunScorer.result`). frames: per-frame figures.
    seconds: total render time of the variant, s. outputs: folder of its 8-bit sRGB frames.
    """

    clip: str
    track: str
    variant: str
    metrics: dict[str, float]
    frames: list[dict[str, float]]
    seconds: float
    outputs: Path


@dataclass
class Ablation:
    """Everything the report needs: results, what was evaluated, what was skipped and why."""

    dataset: Path
    variants: list[Variant]
    settings: ScoreSettings
    max_frames: int | None
    runs: list[RunResult] = field(default_factory=list)
    clips: list[dict] = field(default_factory=list)
    readers: dict[str, ClipReader] = field(default_factory=dict)
    skipped: list[tuple[str, str]] = field(default_factory=list)
    unavailable: list[tuple[str, str]] = field(default_factory=list)
    seconds: float = 0.0


# ----------------------------------------------------------------------------------------
# Report folder handling


def check_report_target(report: Path, force: bool) -> None:
    """Raise OutputError if ``report`` may not be (re)written: it exists without ``force``, is
    a file, or (with ``force``) is a non-empty folder that is not an earlier report."""
    if not report.exists():
        return
    if not report.is_dir():
        raise OutputError(f"Report path '{report}' is a file; choose another -o folder.")
    if not force:
        raise OutputError(f"Report folder '{report}' already exists; pass --force to replace it, "
                          "or choose another -o folder.")
    if any(report.iterdir()) and not (report / "summary.json").is_file():
        raise OutputError(f"Refusing to replace '{report}' with --force: it is not empty and holds no summary.json, "
                          "so it is not an ablation report. Choose another -o folder.")


# ----------------------------------------------------------------------------------------
# Running

REFERENCE_VARIANT = "ours_gt"
"""The variant rendered from the exact inputs: the reference of ``flicker_exact``."""


def _open_clips(ab: Ablation) -> list[tuple[ClipReader, list[str]]]:
    """Readers of the complete clips and their tracks; the others go to ``ab.skipped``."""
    ready = []
    for folder in find_clips(ab.dataset):
        try:
            reader = ClipReader(folder)
            tracks = reader.tracks
            if reader.manifest.get("config", {}).get("dof") is False:
                raise InputError(f"Clip '{folder}' was generated with --no-dof: it has no DOF ground truth to compare "
                                 "with (no dof/<track>/); regenerate it without --no-dof to ablate it.")
            if not tracks:
                raise InputError(f"Clip '{folder}' has no ground-truth DOF track (no dof/<track>/ folder); "
                                 "re-run generate to finish it.")
            reader.check_complete(tracks, ab.max_frames)
        except InputError as ex:
            log.warning("skipping clip %s: %s", folder.name, ex)
            ab.skipped.append((folder.name, str(ex)))
            continue
        ready.append((reader, tracks))
    return ready


def run_variant(reader: ClipReader, track: str, variant: Variant, outputs: Path, settings: ScoreSettings,
                max_frames: int | None = None, progress: Any = None,
                reference: dict[int, np.ndarray] | None = None, keep: dict[int, np.ndarray] | None = None,
                motions: dict[int, tuple[np.ndarray, np.ndarray]] | None = None) -> RunResult:
    """Render ``track`` of a clip with one variant, score every frame, keep 8-bit outputs.

    reference: linear renders from the exact inputs by frame number (``ours_gt``'s outputs),
    scored as ``flicker_exact``. keep: this run *is* that reference: its outputs are stored
    there (and it scores ``flicker_exact`` 0 against itself).
    motions: the input's motion by frame number (:func:`.metrics.evaluation_flow` from each frame
    to the one before), for ``flicker_exact_warped``: it depends only on the clip's input
    frames, so one dict serves every variant and track of a clip; missing entries are computed
    and stored in it.

    Raises InputError (naming the file) when a dataset file cannot be read.
    """
    render = variant.renderer(reader.spec)
    scorer = RunScorer(settings)
    outputs.mkdir(parents=True, exist_ok=True)
    seconds = 0.0
    motions = {} if motions is None else motions
    prev_input: np.ndarray | None = None
    for gt, inputs in variant.inputs(reader.iter_frames(track, max_frames)):
        t0 = time.perf_counter()
        out = render(inputs, gt.focus, gt.aperture)
        seconds += time.perf_counter() - t0
        if out.shape != gt.dof_linear.shape or not np.all(np.isfinite(out)):
            raise RuntimeError(f"variant {variant.name} returned an invalid frame {gt.frame} of "
                               f"{reader.name}/{track}: shape {out.shape}, finite={bool(np.all(np.isfinite(out)))}")
        ref = out if keep is not None else (reference.get(gt.frame) if reference else None)
        motion = None
        if ref is not None and prev_input is not None and prev_input.shape == gt.input_srgb.shape:
            motion = motions.get(gt.frame)
            if motion is None:
                motion = motions[gt.frame] = evaluation_flow(prev_input, gt.input_srgb)
        prev_input = gt.input_srgb
        scorer.add(gt.frame, out, gt.dof_linear, inputs.disparity, gt.disparity, gt.focus, gt.aperture, ref,
                   motion=motion)
        if keep is not None:
            keep[gt.frame] = out
        png = outputs / f"frame_{gt.frame:05d}.png"
        if not cv2.imwrite(str(png), to_uint8(display_srgb(out))[:, :, ::-1]):
            raise OutputError(f"Cannot write '{png}'; check free space and permissions.")
        if progress is not None:
            progress.update(1)
    return RunResult(reader.name, track, variant.name, scorer.result(), scorer.frame_table(), seconds, outputs)


def run_ablation(dataset: str | Path, report: str | Path, *, variants: list[str] | None = None, force: bool = False,
                 max_frames: int | None = None, settings: ScoreSettings | None = None, progress: bool = True,
                 compare_frames: int = 3, estimator_weights: str | Path | None = None) -> Ablation:
    """Run the ablation on a dataset and write the report folder ``report``.

    variants: names from :data:`.variants.VARIANTS` (None = all that can run here).
    max_frames: evaluate only the first N frames of each clip. compare_frames: frames per run
    shown in the side-by-side comparison images. estimator_weights: weights of the RGBD-HDR
    estimator for the ``estimated_*`` rows (None: the shipped weights; without any the rows are
    reported unavailable).
    Raises InputError (not a dataset; no clip usable; unknown or unavailable variant named),
    OutputError (report exists without force).
    """
    from tqdm import tqdm

    from .report import write_report

    t_start = time.perf_counter()
    report = Path(report)
    check_report_target(report, force)
    from . import estimator_inputs

    estimator_inputs.configure(estimator_weights)
    chosen = select(variants)
    ab = Ablation(dataset=Path(dataset), variants=[], settings=settings or ScoreSettings(), max_frames=max_frames)
    for v in chosen:
        reason = v.unavailable()
        if reason:
            if variants:  # asked for by name: do not silently drop it
                raise InputError(f"Variant '{v.name}' cannot run here: {reason}.")
            log.warning("variant %s is unavailable: %s", v.name, reason)
            ab.unavailable.append((v.name, reason))
        else:
            ab.variants.append(v)
    clips = _open_clips(ab)
    if not clips:
        raise InputError("No clip of dataset '{}' can be evaluated:\n{}".format(
            ab.dataset, "\n".join(f"- {name}: {why}" for name, why in ab.skipped)))

    report.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_sibling(report, ".partial")
    tmp.mkdir()
    try:
        total = sum(len(r.frame_numbers(max_frames)) * len(tracks) for r, tracks in clips) * len(ab.variants)
        with tqdm(total=total, unit="frame", disable=not progress, dynamic_ncols=True) as bar:
            for reader, tracks in clips:
                clip_runs: list[RunResult] = []
                motions: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # the clip's input motion
                try:
                    for track in tracks:
                        exact: dict[int, np.ndarray] = {}  # ours_gt's renders (first in table order)
                        for variant in ab.variants:
                            bar.set_description(f"{reader.name}/{track}/{variant.name}")
                            out_dir = tmp / "_frames" / reader.name / track / variant.name
                            is_ref = variant.name == REFERENCE_VARIANT
                            clip_runs.append(run_variant(reader, track, variant, out_dir, ab.settings, max_frames, bar,
                                                         reference=exact or None, keep=exact if is_ref else None,
                                                         motions=motions))
                except InputError as ex:
                    log.warning("skipping clip %s: %s", reader.name, ex)
                    ab.skipped.append((reader.name, str(ex)))
                    shutil.rmtree(tmp / "_frames" / reader.name, ignore_errors=True)
                    continue
                ab.runs.extend(clip_runs)
                ab.readers[reader.name] = reader
                ab.clips.append(reader.summary())
        if not ab.runs:
            raise InputError("No clip of dataset '{}' could be evaluated:\n{}".format(
                ab.dataset, "\n".join(f"- {name}: {why}" for name, why in ab.skipped)))
        ab.seconds = time.perf_counter() - t_start
        write_report(ab, tmp, compare_frames=compare_frames, progress=progress)
        shutil.rmtree(tmp / "_frames", ignore_errors=True)
        replace_folder(tmp, report)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return ab


# ----------------------------------------------------------------------------------------
# Command line


def add_parser(sub) -> argparse.ArgumentParser:
    """Add the ``ablate`` sub-command to an argparse sub-parser set."""
    names = ", ".join(v.name for v in VARIANTS)
    p = sub.add_parser("ablate", help="render every clip under the ablation variants and score them against Cycles",
                       description="Render every clip and focus track of a ground-truth dataset with each variant "
                                   f"({names}) and write a report folder (summary.json, README.md, plots, "
                                   "comparison images and videos).")
    p.add_argument("dataset", metavar="DATASET", help="a clip folder written by `generate`, or a folder of them")
    p.add_argument("-o", "--out", required=True, metavar="REPORT", help="report folder to write")
    p.add_argument("--variants", action="append", metavar="A,B", help=f"variants to run (default: all): {names}")
    p.add_argument("--force", action="store_true", help="replace an existing report folder")
    p.add_argument("--max-frames", type=positive_int, metavar="N", help="evaluate only the first N frames of each clip")
    p.add_argument("--edge-band-px", type=int, default=ScoreSettings.edge_band_px, metavar="PX",
                   help=f"half width of the depth-edge band in px (default {ScoreSettings.edge_band_px})")
    p.add_argument("--compare-frames", type=positive_int, default=3, metavar="K",
                   help="frames per clip and track in the comparison images (default 3)")
    p.add_argument("--estimator-weights", metavar="W",
                   help="RGBD-HDR estimator weights (rvr train's estimator.pt) for the estimated_disparity and "
                        "estimated_hdr rows (default: the shipped weights; without any those rows are unavailable)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    return p


def main(args: argparse.Namespace) -> int:
    """Run ``ablate`` from parsed arguments; returns the process exit code."""
    import sys

    from rvr_addon.errors import RvrError

    from .report import headline_table

    logging.basicConfig(level=logging.INFO if not args.quiet else logging.WARNING, format="%(levelname)s: %(message)s")
    if args.edge_band_px < 0:
        print(f"error: --edge-band-px must be >= 0, got {args.edge_band_px}", file=sys.stderr)
        return 2
    try:
        ab = run_ablation(args.dataset, args.out, variants=args.variants, force=args.force, max_frames=args.max_frames,
                          settings=ScoreSettings(edge_band_px=args.edge_band_px), progress=not args.quiet,
                          compare_frames=args.compare_frames,
                          estimator_weights=getattr(args, "estimator_weights", None))
    except RvrError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("cancelled; no report was written", file=sys.stderr)
        return 130
    print(headline_table(ab))
    note = f", {len(ab.skipped)} clip(s) skipped (see README.md)" if ab.skipped else ""
    print(f"wrote {args.out}: {len(ab.clips)} clip(s), {len(ab.runs)} runs in {ab.seconds:.1f} s{note}")
    return 0
