"""The machinery shared by the resumable stepwise trainers (``rvr train``, ``rvr train-afnet``).

:class:`TrainingRun` owns the run folder (``checkpoint.pt``, ``loss_log.csv``, ``loss.png``,
``run.json``, the exported weights), the checkpoint save/load/restore, the CSV log, the
Ctrl-C-safe update in ``step()`` and the job interface (``step()`` / ``progress`` /
``cancel()`` / ``run()`` with a tqdm bar). A trainer subclass sets the class attributes,
builds its data and calls :meth:`TrainingRun._check_run_dir` and :meth:`TrainingRun._start`
from ``__init__``, and implements ``_backward()`` (its loss and gradients), ``_plot_losses``,
``_run_record`` and ``_export_weights``. The helpers below (:func:`deferred_interrupt`,
:func:`release_memory`, the atomic writers) are the ones both trainers use.
"""
from __future__ import annotations

import contextlib
import csv
import json
import logging
import os
import signal
import threading
import time
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np
import torch

from .errors import InputError
from .interrupts import raise_terminated, sigterm_as_interrupt
from .io.paths import temp_sibling

log = logging.getLogger(__name__)

TRIM_EVERY = 50
"""Iterations between :func:`release_memory` calls."""
_libc: list = []


@contextlib.contextmanager
def deferred_interrupt() -> Iterator[None]:
    """Hold back Ctrl-C (SIGINT) and SIGTERM until the block is done, then raise KeyboardInterrupt.

    Wraps the optimizer update and the checkpoint write, so an interrupt never leaves some
    parameters updated and others not. Outside the main thread (where signal handlers cannot
    be set) it does nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    previous = {sig: signal.signal(sig, lambda signum, frame: caught.append(signum))
                for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if signal.SIGTERM in caught:
        raise_terminated()  # a KeyboardInterrupt that `rvr` reports with exit status 143
    if caught:
        raise KeyboardInterrupt


@contextlib.contextmanager
def terminate_as_interrupt() -> Iterator[None]:
    """Within the block, SIGTERM (a cluster's scheduler, ``kill``) stops like Ctrl-C: it raises
    KeyboardInterrupt (:class:`~.interrupts.Terminated`), so the run saves its checkpoint. (A job
    started in the background by a non-interactive shell ignores SIGINT; SIGTERM still reaches
    it.) Main thread only."""
    with sigterm_as_interrupt():
        yield


def current_rss_mb() -> float:
    """Resident memory of this process in MiB (Linux /proc/self/statm; elsewhere the peak from
    ``resource.getrusage``; NaN when neither is available)."""
    try:
        with open("/proc/self/statm", "rb") as f:
            pages = int(f.read().split()[1])
        return pages * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError, AttributeError):
        pass
    try:
        import resource
        import sys

        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        return peak / 2**20 if sys.platform == "darwin" else peak / 2**10
    except (ImportError, OSError):
        return float("nan")


def release_memory() -> bool:
    """Hand freed heap memory back to the OS (glibc ``malloc_trim(0)``; False where unavailable).

    Training allocates tensors of ever-changing shapes (random crops and scales, a layer count
    that follows the predicted disparity range); glibc then keeps freed blocks in fragmented
    arenas and the resident size creeps up although nothing is referenced: ~20 MB per 100
    iterations in our 500-iteration runs, which over a 150k-iteration run is the order of the
    18 GB an earlier experiment reached. Trimming every ``TRIM_EVERY`` iterations costs ~1 ms.
    """
    if not _libc:
        try:
            import ctypes
            import ctypes.util

            name = ctypes.util.find_library("c")
            lib = ctypes.CDLL(name) if name else None
            _libc.append(lib if lib is not None and hasattr(lib, "malloc_trim") else None)
        except (OSError, AttributeError):
            _libc.append(None)
    lib = _libc[0]
    if lib is None:
        return False
    lib.malloc_trim(0)
    return True


def atomic_torch_save(obj: Any, path: Path) -> None:
    """``torch.save`` to a temp sibling, then rename over ``path`` (no half-written file)."""
    tmp = temp_sibling(path, ".pt")
    try:
        torch.save(obj, tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_text(path: Path, text: str) -> None:
    """Write ``text`` to a temp sibling, then rename over ``path``."""
    tmp = temp_sibling(path, ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def save_png(fig: Any, out: Path) -> None:
    """Lay out a matplotlib figure, save it as PNG atomically (temp sibling, rename) and close it."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    tmp = temp_sibling(out, ".png")
    fig.savefig(tmp, format="png")
    plt.close(fig)
    os.replace(tmp, out)


def save_weights(model: torch.nn.Module, path: Path, weights_format: str, header: dict) -> Path:
    """Write ``{"format", "header" (JSON text), "state_dict"}`` atomically, and the header as .json."""
    path = Path(path)
    state = {k: v.detach().clone() for k, v in model.state_dict().items()}
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_torch_save({"format": weights_format, "header": json.dumps(header), "state_dict": state}, path)
    atomic_text(path.with_suffix(".json"), json.dumps(header, indent=1))
    return path


class TrainingRun:
    """Base of a resumable training run (module docstring); subclasses set the class attributes.

    ``settings`` needs ``run_dir``, ``resume``, ``iterations``, ``checkpoint_every``, ``lr``,
    ``seed`` and ``grad_clip``; ``model`` a ``config`` with ``to_dict()``.
    """

    checkpoint_format: str = ""
    """``"format"`` of checkpoint.pt; a checkpoint of another format is refused."""
    log_fields: tuple[str, ...] = ()
    """Columns of loss_log.csv (start with ``iteration``, ``wall_s``)."""
    weights_name: str = ""
    """File the finished run exports its weights to (in the run folder)."""
    bar_desc: str = "train"
    run_noun: str = "a training run"
    """In "'RUN_DIR' already holds <run_noun> (checkpoint.pt)"."""
    checkpoint_noun: str = "a training checkpoint"
    """In "'checkpoint.pt' is not <checkpoint_noun> (<format>)"."""
    blank_nonfinite: bool = False
    """Log a non-finite part as an empty cell instead of ``nan``."""

    settings: Any
    model: torch.nn.Module
    optimizer: torch.optim.Optimizer
    rng: np.random.Generator
    iteration: int
    wall_before: float

    # -- setup (called from the subclass's __init__) ----------------------------------------
    def _check_run_dir(self) -> None:
        """Set the run-folder paths; refuse to overwrite a run, to resume a missing one, or to both
        resume and start from other weights (``init_from``)."""
        s = self.settings
        if s.resume and getattr(s, "init_from", None) is not None:
            raise InputError("--init-from starts a new run; --resume continues one from its checkpoint: "
                             "give one of them")
        self.run_dir = Path(s.run_dir)
        self.checkpoint_path = self.run_dir / "checkpoint.pt"
        self.log_path = self.run_dir / "loss_log.csv"
        if self.checkpoint_path.exists() and not s.resume:
            raise InputError(f"'{self.run_dir}' already holds {self.run_noun} (checkpoint.pt): pass --resume to "
                             "continue it, or choose a new -o folder")
        if s.resume and not self.checkpoint_path.exists():
            raise InputError(f"--resume: '{self.checkpoint_path}' does not exist; start the run without --resume")

    def _start(self, build_model: Callable[[], torch.nn.Module], checkpoint: dict | None) -> None:
        """Seed, build the model (after seeding) and Adam, restore ``checkpoint``, open the log, write run.json."""
        s = self.settings
        torch.manual_seed(s.seed)
        self.rng = np.random.default_rng(s.seed)
        self.model = build_model()
        self.optimizer = torch.optim.Adam(self.model.parameters(), lr=s.lr)
        self.iteration = 0
        self.wall_before = 0.0
        if checkpoint is not None:
            self._restore(checkpoint)
        self._started = time.perf_counter()
        self._cancelled = False
        self._finished = False
        self.last: dict[str, float] = {}
        self._log_file = None
        self._open_log()
        atomic_text(self.run_dir / "run.json", json.dumps(self._run_record(), indent=1))

    # -- checkpoints ----------------------------------------------------------------------
    def _load_checkpoint(self) -> dict:
        try:
            ck = torch.load(self.checkpoint_path, map_location="cpu", weights_only=True)
        except Exception as ex:  # noqa: BLE001 - any unpickling failure means a corrupt file
            raise InputError(f"checkpoint '{self.checkpoint_path}' cannot be read ({type(ex).__name__}: {ex}); it is "
                             "corrupt. Delete it to start over (or restore a copy).") from ex
        if not isinstance(ck, dict) or ck.get("format") != self.checkpoint_format:
            raise InputError(f"'{self.checkpoint_path}' is not {self.checkpoint_noun} ({self.checkpoint_format})")
        return ck

    def _restore(self, ck: dict) -> None:
        self.model.load_state_dict(ck["model"])
        self.optimizer.load_state_dict(ck["optimizer"])
        for group in self.optimizer.param_groups:
            group["lr"] = self.settings.lr
        self.iteration = int(ck["iteration"])
        self.wall_before = float(ck["wall_time_s"])
        self.rng.bit_generator.state = json.loads(ck["numpy_rng"])
        torch.set_rng_state(ck["torch_rng"])
        log.info("resumed %s at iteration %d", self.checkpoint_path, self.iteration)

    def save_checkpoint(self) -> None:
        """Write checkpoint.pt atomically (model, Adam, iteration, RNG, wall time)."""
        atomic_torch_save({
            "format": self.checkpoint_format, "iteration": self.iteration, "wall_time_s": self.wall_time,
            "model_config": json.dumps(self.model.config.to_dict()), "model": self.model.state_dict(),
            "optimizer": self.optimizer.state_dict(), "numpy_rng": json.dumps(self.rng.bit_generator.state),
            "torch_rng": torch.get_rng_state(),
        }, self.checkpoint_path)
        if self._log_file is not None:
            self._log_file.flush()

    @property
    def wall_time(self) -> float:
        """Training seconds over all sessions of this run."""
        return self.wall_before + (time.perf_counter() - self._started)

    # -- log and plot ---------------------------------------------------------------------
    def _open_log(self) -> None:
        """(Re)write loss_log.csv without the rows past the checkpoint, then open it for appending."""
        rows = []
        if self.log_path.exists() and self.settings.resume:
            with self.log_path.open(newline="") as f:
                rows = [r for r in csv.DictReader(f) if r.get("iteration", "").isdigit()
                        and int(r["iteration"]) <= self.iteration]
        tmp = temp_sibling(self.log_path, ".csv")
        with tmp.open("w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=self.log_fields)
            w.writeheader()
            w.writerows({k: r.get(k, "") for k in self.log_fields} for r in rows)
        os.replace(tmp, self.log_path)
        self._log_file = self.log_path.open("a", newline="")
        self._log = csv.DictWriter(self._log_file, fieldnames=self.log_fields)

    def _plot_losses(self, out: Path) -> None:
        """Plot loss_log.csv to ``out`` (subclass; may raise ImportError without matplotlib)."""
        raise NotImplementedError

    def plot(self) -> None:
        """Write loss.png (skipped with one warning without matplotlib; the CSV log has it all)."""
        if self._log_file is not None:
            self._log_file.flush()
        try:
            self._plot_losses(self.run_dir / "loss.png")
        except ImportError as ex:
            if not getattr(self, "_warned_plot", False):
                log.warning("no loss plot (%s); install matplotlib for loss.png, the numbers are in %s",
                            ex, self.log_path)
                self._warned_plot = True

    # -- the job --------------------------------------------------------------------------
    @property
    def progress(self) -> float:
        """Fraction of the iterations done, 0..1."""
        return min(self.iteration / self.settings.iterations, 1.0)

    @property
    def done(self) -> bool:
        """True once the run reached its iteration count or was cancelled."""
        return self.iteration >= self.settings.iterations or self._cancelled

    @property
    def text(self) -> str:
        """One status line (the Job protocol, ``rvr_addon.jobs``): iterations done, or how it ended."""
        n = self.settings.iterations
        if self._cancelled:
            return f"cancelled at iteration {self.iteration} of {n}; checkpoint saved in {self.run_dir}"
        return f"iteration {self.iteration} of {n}"

    def _backward(self) -> tuple[dict[str, float], dict[str, str]]:
        """Draw a batch, compute its loss and gradients (subclass; RvrError on a non-finite loss).
        Returns the float parts for the log (``total`` among them) and extra text columns of the row."""
        raise NotImplementedError

    def step(self) -> bool:
        """One optimisation step; False once the run has reached its iteration count.

        The subclass's :meth:`_backward` fills the gradients; then the gradient norm is clipped,
        Adam steps, the iteration is counted, ``parts`` (plus ``grad_norm``, ``rss_mb`` and the
        extra columns) become one log row and a checkpoint is written when due, all with Ctrl-C
        held back; then the loss plot is refreshed when due and the run finishes at the end.
        """
        if self.done:
            return False
        s = self.settings
        self.model.train()
        self.optimizer.zero_grad(set_to_none=True)
        parts, extra = self._backward()
        with deferred_interrupt():  # the update, its count and its log row happen together or not at all
            norm = torch.nn.utils.clip_grad_norm_(self.model.parameters(), s.grad_clip)
            self.optimizer.step()
            if (self.iteration + 1) % TRIM_EVERY == 0:
                release_memory()
            parts["grad_norm"] = float(norm)
            parts["rss_mb"] = current_rss_mb()
            self.iteration += 1
            self.last = parts
            row = {k: "" for k in self.log_fields}
            row.update({k: f"{v:.6g}" for k, v in parts.items()
                        if k in self.log_fields and not (self.blank_nonfinite and not np.isfinite(v))})
            row.update(iteration=self.iteration, wall_s=f"{self.wall_time:.2f}", **extra)
            self._log.writerow(row)
            if self.iteration % s.checkpoint_every == 0:
                self.save_checkpoint()
        if self.iteration % s.checkpoint_every == 0:
            self.plot()
        if self.iteration >= s.iterations:
            self.finish()
            return False
        return True

    def finish(self) -> None:
        """Final checkpoint, plot and exported weights."""
        self._finished = True
        self.save_checkpoint()
        self.plot()
        self.export(self.run_dir / self.weights_name)
        self.close()

    def cancel(self) -> None:
        """Stop (Ctrl-C, Esc): save a checkpoint so ``--resume`` continues from here. After the
        end (or a cancel) it does nothing: the final checkpoint and weights stay as written."""
        if self._finished or self._cancelled:
            return
        self._cancelled = True
        self.save_checkpoint()
        self.plot()
        self.close()

    def close(self) -> None:
        """Close the log file (idempotent)."""
        if self._log_file is not None:
            self._log_file.close()
            self._log_file = None

    def run(self, progress: bool = True) -> None:
        """Run to the end with a tqdm bar; on Ctrl-C or SIGTERM save a checkpoint, then raise
        KeyboardInterrupt."""
        from tqdm import tqdm

        s = self.settings
        bar = tqdm(total=s.iterations, initial=self.iteration, unit="it", desc=self.bar_desc, disable=not progress)
        try:
            with terminate_as_interrupt():
                while self.step():
                    bar.update(1)
                    if self.iteration % 10 == 0:
                        bar.set_postfix(loss=f"{self.last.get('total', 0):.4f}", refresh=False)
                if not self._cancelled and not self._finished:  # resumed at (or past) its count: export it now
                    self.finish()
            bar.update(max(0, s.iterations - bar.n))
        except KeyboardInterrupt:
            self.cancel()
            raise
        except BaseException:
            self.close()
            raise
        finally:
            bar.close()

    # -- export ---------------------------------------------------------------------------
    def _run_record(self) -> dict:
        """Settings and training-data summary for run.json (subclass)."""
        raise NotImplementedError

    def _export_weights(self, path: Path, training: dict) -> Path:
        """Write the weights file with ``training`` in its header (subclass)."""
        raise NotImplementedError

    def export(self, path: Path) -> Path:
        """Write the shippable weights file (state dict + JSON header) and a .json copy of the header."""
        training = {k: v for k, v in self._run_record().items() if k not in ("model", "parameters", "engine_version")}
        return self._export_weights(path, training)


def previous_init_record(run_json: Path) -> dict | None:
    """The ``init_from`` record of a resumed run (None when it started from scratch or is unknown)."""
    try:
        return json.loads(run_json.read_text()).get("init_from")
    except (OSError, ValueError, AttributeError):
        return None
