"""The outcome of a batch: one row per clip and the summary table printed at the end."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

STATUSES = ("done", "skipped", "failed")


@dataclass
class ClipOutcome:
    """One clip's result. status: done / skipped (finished by an earlier run) / failed.
    frames: frames of the clip (0 when it could not be probed); reason: why it failed;
    task_seconds / task_cpu_seconds: summed task wall / CPU time per stage (s), from the workers."""

    source: Path
    name: str
    status: str
    frames: int = 0
    reason: str = ""
    outputs: list[str] = field(default_factory=list)
    task_seconds: dict[str, float] = field(default_factory=dict)
    task_cpu_seconds: dict[str, float] = field(default_factory=dict)


@dataclass
class BatchReport:
    """All clips of a run plus its wall time (s, from the first submitted task to the last
    result; cluster start-up excluded, reported as startup_s) and the worker count."""

    clips: list[ClipOutcome]
    wall_s: float
    startup_s: float = 0.0
    workers: int = 0
    dashboard: str | None = None

    def count(self, status: str) -> int:
        """Number of clips with that status."""
        return sum(1 for c in self.clips if c.status == status)

    @property
    def frames_done(self) -> int:
        """Frames of the clips processed in this run (skipped ones not counted)."""
        return sum(c.frames for c in self.clips if c.status == "done")

    @property
    def fps(self) -> float:
        """Frames processed per second of wall time (every stage: analyze, autofocus, render)."""
        return self.frames_done / self.wall_s if self.wall_s > 0 else 0.0

    def stage_seconds_per_frame(self, cpu: bool = False) -> dict[str, float]:
        """Summed task wall time (cpu: CPU time) per stage divided by the frames done (s/frame)."""
        total: dict[str, float] = {}
        for c in self.clips:
            if c.status == "done":
                for k, v in (c.task_cpu_seconds if cpu else c.task_seconds).items():
                    total[k] = total.get(k, 0.0) + v
        n = max(self.frames_done, 1)
        return {k: v / n for k, v in total.items()}

    def table(self) -> str:
        """The summary table (plain text) for the end of ``rvr batch``."""
        width = max([len(c.name) for c in self.clips] + [4])
        lines = [f"{'clip':<{width}}  {'status':<7}  {'frames':>6}  {'task s':>7}  reason / outputs"]
        for c in self.clips:
            busy = sum(c.task_seconds.values())
            tail = c.reason.splitlines()[0] if c.status == "failed" and c.reason else \
                ", ".join(Path(o).name for o in c.outputs)
            lines.append(f"{c.name:<{width}}  {c.status:<7}  {c.frames:>6}  {busy:>7.1f}  {tail}")
        lines.append(f"clips done {self.count('done')}, skipped (already finished) {self.count('skipped')}, "
                     f"failed {self.count('failed')}; {self.frames_done} frames in {self.wall_s:.1f} s = "
                     f"{self.fps:.2f} frames/s on {self.workers} worker(s)"
                     + (f" (cluster start-up {self.startup_s:.1f} s not included)" if self.startup_s else ""))
        details = [c for c in self.clips if c.status == "failed" and "\n" in c.reason]
        for c in details:
            lines.append(f"--- {c.name}: {c.reason}")
        per = self.stage_seconds_per_frame()
        if per:
            cpu = self.stage_seconds_per_frame(cpu=True)
            lines.append("task time per frame (wall / CPU): " + ", ".join(
                f"{k} {v:.3f} / {cpu.get(k, 0.0):.3f} s" for k, v in per.items()))
        return "\n".join(lines)
