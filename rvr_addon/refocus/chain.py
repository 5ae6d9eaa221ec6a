"""One job made of several jobs run in turn (the shape every front end drives: step, cancel,
progress, text).

A stage is built only when the stages before it are done (its inputs exist then), and its
``finish`` callback runs once it has stepped to the end (e.g. writing the focus file the next
stage reads).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable


@dataclass
class Stage:
    """name: shown to the user. weight: its share of the whole run's time (relative units, e.g.
    seconds a frame x frames), for the progress and the ETA. build: makes the job (called when
    the stage starts; may return None = nothing to do, e.g. a result reused from an earlier run).
    finish: called with the job once it is done. frames: the frames it works through (for the
    ``frame i/n`` display of jobs that count only their progress)."""

    name: str
    weight: float
    build: Callable[[], Any]
    finish: Callable[[Any], None] | None = None
    frames: int = 0


class JobChain:
    """Run ``stages`` in order as one job: ``while chain.step(): pass``; ``cancel()`` stops the
    stage in progress (which keeps what it has finished, as each job does on its own)."""

    def __init__(self, stages: list[Stage]) -> None:
        self.stages = stages
        self.index = 0
        self.job: Any = None
        self.seconds: dict[str, float] = {}
        self.skipped: list[str] = []
        self._t0: float | None = None
        self._finished = not stages
        self.text = "ready"

    @property
    def stage(self) -> Stage | None:
        """The stage in progress (None once every stage is done)."""
        return self.stages[self.index] if self.index < len(self.stages) else None

    @property
    def progress(self) -> float:
        """Fraction of the whole run done, 0..1, each stage counting its weight."""
        total = sum(max(s.weight, 0.0) for s in self.stages)
        if total <= 0:
            return 1.0 if self._finished else 0.0
        done = sum(max(s.weight, 0.0) for s in self.stages[:self.index])
        if self.job is not None and self.stage is not None:
            done += max(self.stage.weight, 0.0) * float(getattr(self.job, "progress", 0.0))
        return min(done / total, 1.0)

    def frame_text(self) -> str:
        """``frame i/n`` of the stage in progress (from its ``done``/``total``, else its progress
        over ``stage.frames``), or "" when it counts no frames."""
        job, stage = self.job, self.stage
        if job is None or stage is None:
            return ""
        done, total = getattr(job, "done", None), getattr(job, "total", None)
        if not isinstance(done, int) or not isinstance(total, int) or total <= 0:
            if not stage.frames:
                return ""
            done, total = int(float(getattr(job, "progress", 0.0)) * stage.frames), stage.frames
        return f"frame {min(done, total)}/{total}"

    def step(self) -> bool:
        """Advance the stage in progress by one step (starting it when due); False when all are done."""
        while not self._finished:
            stage = self.stages[self.index]
            if self.job is None:
                self._t0 = time.perf_counter()
                self.job = stage.build()
                if self.job is None:
                    self.skipped.append(stage.name)
                    self._next(stage)
                    continue
                self.text = f"{stage.name}: {getattr(self.job, 'text', '')}"
            if self.job.step():
                self.text = f"{stage.name}: {getattr(self.job, 'text', '')}"
                return True
            if stage.finish is not None:
                stage.finish(self.job)
            self._next(stage)
            return not self._finished
        return False

    def _next(self, stage: Stage) -> None:
        self.seconds[stage.name] = self.seconds.get(stage.name, 0.0) + time.perf_counter() - (self._t0 or 0.0)
        self.job = None
        self.index += 1
        if self.index >= len(self.stages):
            self._finished = True
            self.text = "done"

    def cancel(self) -> None:
        """Stop: the stage in progress is cancelled (its own cancel keeps earlier results).
        Idempotent; after the end it changes nothing."""
        if self._finished:
            return
        job, self.job = self.job, None
        self._finished = True
        if job is not None and hasattr(job, "cancel"):
            job.cancel()
        name = self.stage.name if self.stage is not None else "the last stage"
        self.text = f"cancelled during {name}"
