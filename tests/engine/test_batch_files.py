"""Issue 22.4: ``rvr batch``'s work files are data, never code. A file planted in the work folder
(a pickle that would run a command, an .npz hiding a pickled object array) is refused or measured
again with a message, and nothing in it runs. Plus the tree-wide audit: no pickle.load, every
torch.load weights_only=True, no np.load(allow_pickle=True)."""
from __future__ import annotations

import logging
import pickle
import re
import zipfile
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from rvr_addon.errors import InputError
from rvr_addon.io.datafile import DataFileError, DataReader, DataWriter
from rvr_addon.laaf.analysis import FrameMeasurement, read_header, read_measurements, write_measurements

ROOT = Path(__file__).resolve().parents[2]
W, H, N = 48, 32, 6


class Payload:
    """Unpickling this runs ``marker.write_text('owned')``: what a planted file would do."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.write_text, (self.marker, "owned"))


def _measurement(t: int) -> FrameMeasurement:
    rgb = np.full((4, 6, 3), t, np.uint8)
    features = {"face": [(1.0, 2.0, 3.0, np.float32(4.5))] if t % 2 else None,
                "speech": ([(0.5, None), None], np.arange(6, dtype=np.float32).reshape(2, 3), [0.25, None]),
                "action": (np.ones((2, 2), np.float32), bool(t % 2)), "saliency": np.zeros((4, 6), np.float32),
                "odd": {3: float("nan"), "x": (np.int64(7), "s")}}
    return FrameMeasurement(t, rgb, np.full((4, 6), 0.5 * t, np.float32) if t else None, features,
                            {"decode": 0.1 * t, "face": 0.2})


def _same(a, b) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return type(a) is type(b) and a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b, equal_nan=True)
    if isinstance(a, (list, tuple)):
        return type(a) is type(b) and len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, dict):
        return type(b) is dict and list(a) == list(b) and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, float) and np.isnan(a):
        return isinstance(b, float) and np.isnan(b)
    return type(a) is type(b) and a == b


def test_measurements_round_trip_exactly_without_pickle(tmp_path):
    path = tmp_path / "analysis_000002_000005.npz"
    frames = [_measurement(t) for t in range(2, 5)]
    assert write_measurements(path, {"range": (2, 5)}, iter(frames)) == 3
    assert zipfile.is_zipfile(path) and not list(tmp_path.glob(".*"))  # no temp left
    assert read_header(path)["range"] == (2, 5)
    back = list(read_measurements([path]))
    for m, r in zip(frames, back):
        assert _same((m.t, m.rgb, m.disparity, m.features, m.seconds), (r.t, r.rgb, r.disparity, r.features, r.seconds))
    # every member loads with allow_pickle=False: nothing in the file is a pickle
    with np.load(path, allow_pickle=False) as z:
        for key in z.files:
            assert z[key].dtype != object


def test_only_data_can_be_stored(tmp_path):
    with DataWriter(tmp_path / "x.npz") as out:
        with pytest.raises(TypeError, match="cannot be stored"):
            out.put("a", {"obj": object()})
        with pytest.raises(TypeError, match="dtype object"):
            out.put("b", np.array([None, 1], dtype=object))


def _planted_pickle(path: Path, marker: Path) -> None:
    path.write_bytes(pickle.dumps({"format": "rvr-laaf-analysis/2", "range": (0, N), "x": Payload(marker)}))


def _planted_npz_object_array(path: Path, marker: Path) -> None:
    """A well-formed archive whose header is fine and whose frame is a pickled object array."""
    with DataWriter(path) as out:
        out.put("header", {"format": "rvr-laaf-analysis/2", "range": (0, 1), "frames": 1})
    with zipfile.ZipFile(path, "a") as zf, zf.open("f0.npy", "w") as f:
        np.lib.format.write_array(f, np.array([Payload(marker)], dtype=object), allow_pickle=True)


def _planted_npz_header_object(path: Path, marker: Path) -> None:
    np.savez(path, header=np.array([Payload(marker)], dtype=object))


PLANTS = {"pickle": _planted_pickle, "npz_object_frame": _planted_npz_object_array,
          "npz_object_header": _planted_npz_header_object}


@pytest.mark.parametrize("plant", list(PLANTS))
def test_a_planted_work_file_is_refused_and_never_runs(tmp_path, plant, caplog):
    marker = tmp_path / "owned.txt"
    path = tmp_path / "work" / "analysis_000000_000006.npz"
    path.parent.mkdir()
    PLANTS[plant](path, marker)
    with pytest.raises(ValueError):  # the file really holds a pickle (NumPy refuses it without allow_pickle)
        with np.load(path, allow_pickle=False) as z:
            [z[k] for k in z.files]
    if plant == "npz_object_frame":
        assert read_header(path) is not None  # the header alone is plain data...
    else:
        with caplog.at_level(logging.WARNING):
            assert read_header(path) is None
        assert "LAAF measurement file" in caplog.text and "measures these frames again" in caplog.text
    with pytest.raises(InputError, match=re.escape(str(path))):
        list(read_measurements([path]))  # ...but the frames are refused, naming the file and the fix
    assert not marker.exists()  # nothing ran


def test_batch_measures_a_planted_chunk_again_with_a_message(tmp_path, monkeypatch, caplog):
    """stages.laaf_measure: a planted file at the chunk's path is measured again (not trusted, not run)."""
    from rvr_addon.batch import stages
    from rvr_addon.laaf.lookahead import AutofocusSettings

    clip = tmp_path / "clip"
    clip.mkdir()
    rng = np.random.default_rng(0)
    for i in range(N):
        cv2.imwrite(str(clip / f"f{i:03d}.png"), (rng.random((H, W, 3)) * 255).astype(np.uint8))
    depth = tmp_path / "depth.npy"
    np.save(depth, np.tile(np.linspace(-2, 6, W, dtype=np.float32), (H, 1)))
    plan = SimpleNamespace(work=tmp_path / "work", source=clip, cache=None)
    plan.work.mkdir()
    monkeypatch.setattr(stages, "autofocus_settings",
                        lambda plan, settings: AutofocusSettings(input=clip, depth=depth, preset="salient"))
    marker = tmp_path / "owned.txt"
    path = stages.analysis_path(plan, 0, N)
    assert path.suffix == ".npz"
    _planted_pickle(path, marker)
    with caplog.at_level(logging.WARNING):
        result = stages.laaf_measure(plan, None, 0, N, {})
    assert result["reused"] is False and result["frames"] == N
    assert "LAAF measurement file" in caplog.text and "measures these frames again" in caplog.text
    assert not marker.exists()
    assert [m.t for m in read_measurements([path])] == list(range(N))
    assert stages.laaf_measure(plan, None, 0, N, {})["reused"] is True  # complete now: kept


def test_the_tree_loads_nothing_that_can_run_code():
    """Audit of the engine, operators, harness, benches and scripts (tests may pickle on purpose)."""
    bad = []
    for folder in ("rvr_addon", "operators", "panels", "sintel_eval", "bench", "scripts"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            text = path.read_text(encoding="utf-8")
            where = path.relative_to(ROOT)
            for pattern, why in ((r"\bpickle\.loads?\(|\bcloudpickle\.|\bdill\.|\bjoblib\.load\(", "unpickles"),
                                 (r"allow_pickle\s*=\s*True", "np.load with allow_pickle=True"),
                                 (r"\bpd\.read_pickle|\.to_pickle\(|\bshelve\.|\bmarshal\.loads?\(", "pickle-based")):
                if re.search(pattern, text):
                    bad.append(f"{where}: {why}")
            for call in re.finditer(r"torch\.load\(", text):
                args = text[call.end():call.end() + 200].split(")\n")[0]
                if "weights_only=True" not in args:
                    bad.append(f"{where}: torch.load without weights_only=True")
    assert not bad, bad


def test_a_reader_refuses_a_truncated_archive(tmp_path):
    path = tmp_path / "a.npz"
    write_measurements(path, {"range": (0, 2)}, iter([_measurement(0), _measurement(1)]))
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    assert read_header(path) is None
    with pytest.raises(InputError, match="delete it and re-run"):
        list(read_measurements([path]))
    with pytest.raises(DataFileError):
        DataReader(tmp_path / "missing.npz")
