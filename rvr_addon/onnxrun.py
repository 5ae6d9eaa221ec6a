"""ONNX Runtime for inference without torch: the shipped networks exported to ONNX
(``scripts/export_onnx.py``, :mod:`rvr_addon.onnx_export`) run here in the Blender extension,
whose zip bundles onnxruntime but not torch.

Which backend runs a network (:func:`backend`): ``RVR_INFERENCE=torch|onnx|auto`` in the
environment; ``auto`` (the default) picks per network what was faster on this 2-core CPU (the
model cards): the estimator runs with torch where torch is importable, AF-Net with ONNX Runtime
where onnxruntime is; each falls back to the other, and a network whose ``.pt`` is absent (the
extension zip ships only the exports) runs its ``.onnx``. Training always uses torch.

Each exported file records in its metadata (``metadata_props``) the weights it came from:
``rvr_source_hash`` (first 16 hex digits of the SHA-256 of the ``.pt`` file, what the caches and
batch fingerprints key on), ``rvr_header`` (the weights' JSON header) and ``rvr_graph`` (which
part of the network the graph holds). No torch import here.
"""
from __future__ import annotations

import hashlib
import importlib.util
import json
import os
from dataclasses import dataclass
from pathlib import Path

from .errors import InputError

BACKENDS = ("auto", "torch", "onnx")
ENV = "RVR_INFERENCE"
"""Environment variable choosing the inference backend (:data:`BACKENDS`)."""
INSTALL_HELP = ("install onnxruntime (`pip install onnxruntime==1.31.1`; the Blender extension zip bundles it) "
                "or torch")


def has_torch() -> bool:
    """Whether torch can be imported (without importing it)."""
    return importlib.util.find_spec("torch") is not None


def has_onnxruntime() -> bool:
    """Whether onnxruntime can be imported (without importing it)."""
    return importlib.util.find_spec("onnxruntime") is not None


def backend(requested: str | None = None) -> str:
    """The requested backend (argument, else ``$RVR_INFERENCE``, else ``auto``), validated."""
    value = (requested or os.environ.get(ENV) or "auto").strip().lower()
    if value not in BACKENDS:
        raise InputError(f"inference backend {value!r} (from {ENV} or an option) is not one of {', '.join(BACKENDS)}")
    return value


def file_hash(path: str | Path) -> str:
    """First 16 hex digits of the SHA-256 of a file (the id caches record for weights)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


@dataclass
class OnnxGraph:
    """One exported graph: its session, metadata and path."""

    session: object
    meta: dict[str, str]
    path: Path

    @property
    def header(self) -> dict:
        """The weights' JSON header recorded at export."""
        return json.loads(self.meta.get("rvr_header", "{}"))

    @property
    def source_hash(self) -> str:
        """The hash of the ``.pt`` file the graph was exported from."""
        return self.meta.get("rvr_source_hash", "")

    def run(self, feeds: dict) -> list:
        """Run the graph on numpy feeds; returns every output as a numpy array."""
        return self.session.run(None, feeds)


def threads() -> int:
    """Intra-op threads for ONNX Runtime: ``$RVR_ONNX_THREADS``, else the CPUs this process may use."""
    env = os.environ.get("RVR_ONNX_THREADS")
    if env and env.isdigit() and int(env) > 0:
        return int(env)
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except (AttributeError, OSError):
        return max(os.cpu_count() or 1, 1)


def load_graph(path: str | Path, graph: str, n_threads: int | None = None) -> OnnxGraph:
    """An ONNX Runtime session on the CPU for ``path``, whose metadata must say ``rvr_graph == graph``.

    Raises InputError naming the file when onnxruntime is missing or the file is missing,
    unreadable or another graph."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"ONNX model '{path}' not found; regenerate it with `python scripts/export_onnx.py` "
                         "(needs torch and onnx) or restore it from the repository")
    try:
        import onnxruntime as ort
    except ImportError as ex:
        raise InputError(f"running '{path.name}' needs onnxruntime, which is not importable ({ex}); "
                         f"{INSTALL_HELP}") from ex
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = int(n_threads or threads())
    opts.inter_op_num_threads = 1
    opts.log_severity_level = 3
    try:
        session = ort.InferenceSession(str(path), sess_options=opts, providers=["CPUExecutionProvider"])
    except Exception as ex:  # noqa: BLE001 - onnxruntime raises its own exception types
        raise InputError(f"ONNX model '{path}' cannot be loaded ({type(ex).__name__}: {ex}); regenerate it with "
                         "`python scripts/export_onnx.py`") from ex
    meta = dict(session.get_modelmeta().custom_metadata_map)
    if meta.get("rvr_graph") != graph:
        raise InputError(f"'{path}' holds the graph {meta.get('rvr_graph')!r}, not {graph!r}; regenerate it with "
                         "`python scripts/export_onnx.py`")
    return OnnxGraph(session, meta, path)


def matching_onnx(weights: Path, onnx_path: Path) -> bool:
    """Whether ``onnx_path`` exists and was exported from ``weights`` (its recorded source hash),
    read from the ONNX file's metadata without onnxruntime when ``weights`` is absent (then any
    exported file counts)."""
    if not onnx_path.is_file():
        return False
    if not weights.is_file() or weights.suffix == ".onnx":
        return True  # nothing to compare with (only the export ships), or the export itself
    try:
        return read_metadata(onnx_path).get("rvr_source_hash") == file_hash(weights)
    except (OSError, ValueError):
        return False


def read_metadata(path: str | Path) -> dict[str, str]:
    """``metadata_props`` of an ONNX file, parsed from its protobuf bytes with the standard library
    (fields 14 = metadata_props of ModelProto, with key 1 and value 2)."""
    data = Path(path).read_bytes()
    out: dict[str, str] = {}
    for field, value in _fields(data):
        if field == 14 and isinstance(value, bytes):
            entry = dict((f, v) for f, v in _fields(value) if isinstance(v, bytes))
            out[entry.get(1, b"").decode()] = entry.get(2, b"").decode()
    return out


def _varint(data: bytes, i: int) -> tuple[int, int]:
    shift = result = 0
    while True:
        if i >= len(data):
            raise ValueError("truncated protobuf varint")
        b = data[i]
        i += 1
        result |= (b & 0x7F) << shift
        if not b & 0x80:
            return result, i
        shift += 7


def _fields(data: bytes):
    """(field number, int or bytes) of the top-level fields of a protobuf message."""
    i = 0
    while i < len(data):
        key, i = _varint(data, i)
        field, wire = key >> 3, key & 7
        if wire == 0:
            value, i = _varint(data, i)
        elif wire == 2:
            n, i = _varint(data, i)
            value, i = data[i:i + n], i + n
        elif wire == 1:
            value, i = int.from_bytes(data[i:i + 8], "little"), i + 8
        elif wire == 5:
            value, i = int.from_bytes(data[i:i + 4], "little"), i + 4
        else:
            raise ValueError(f"unsupported protobuf wire type {wire}")
        yield field, value
