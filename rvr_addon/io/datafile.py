"""Data-only work files: nested values as JSON plus NumPy arrays in one ``.npz``, never pickle.

A work file the engine reads back (``rvr batch``'s LAAF measurements) may have been replaced
by anyone who can write the output folder, so it must not be able to run code when loaded.
Here nothing is unpickled: the archive is a zip of ``.npy`` members written and read with
``allow_pickle=False`` (an object array in a planted file is refused by NumPy), and the
structure around the arrays is JSON with a few tags:

* ``None``, bool, int, float (NaN/inf too), str, list: as JSON;
* tuple: ``{"__tuple__": [...]}``; dict: ``{"__dict__": [[key, value], ...]}`` (any keys);
* ``np.ndarray`` (not object dtype): ``{"__array__": name}`` of a member; a NumPy scalar:
  ``{"__scalar__": name}`` (a 0-d member, read back as the same NumPy type).

Anything else cannot be stored (TypeError), so what comes back is exactly what went in.
"""
from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError

TAGS = ("__tuple__", "__dict__", "__array__", "__scalar__")


class DataFileError(InputError):
    """A data file is missing, truncated, not one, or holds something other than data."""


def _put_array(zf: zipfile.ZipFile, name: str, array: np.ndarray) -> None:
    if array.dtype.hasobject:
        raise TypeError(f"array '{name}' has dtype {array.dtype}; only plain numeric/bool/str arrays are stored")
    with zf.open(name + ".npy", "w", force_zip64=True) as f:
        np.lib.format.write_array(f, np.asanyarray(array), allow_pickle=False)


class DataWriter:
    """Stream values into a data archive: ``put(name, value)`` one after the other, then ``close()``."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._zip = zipfile.ZipFile(self.path, "w", compression=zipfile.ZIP_STORED, allowZip64=True)
        self._count = 0

    def put(self, name: str, value: Any) -> None:
        """Store ``value`` (see the module docstring) under ``name`` (a plain word)."""
        if not name.isidentifier():
            raise ValueError(f"data file member name {name!r} must be a plain word")
        doc = self._encode(value, name)
        data = np.frombuffer(json.dumps(doc, allow_nan=True).encode("utf-8"), np.uint8)
        _put_array(self._zip, name, data)

    def _encode(self, value: Any, prefix: str) -> Any:
        if value is None or isinstance(value, (bool, int, float, str)) and not isinstance(value, np.generic):
            return value
        if isinstance(value, np.ndarray):
            key = self._member(prefix)
            _put_array(self._zip, key, value)
            return {"__array__": key}
        if isinstance(value, np.generic):
            key = self._member(prefix)
            _put_array(self._zip, key, np.asarray(value))
            return {"__scalar__": key}
        if isinstance(value, tuple):
            return {"__tuple__": [self._encode(v, prefix) for v in value]}
        if isinstance(value, list):
            return [self._encode(v, prefix) for v in value]
        if isinstance(value, dict):
            return {"__dict__": [[self._encode(k, prefix), self._encode(v, prefix)] for k, v in value.items()]}
        raise TypeError(f"{type(value).__name__} cannot be stored in a data file ({self.path})")

    def _member(self, prefix: str) -> str:
        self._count += 1
        return f"{prefix}__a{self._count}"

    def close(self) -> None:
        """Finish the archive (its central directory is written now)."""
        self._zip.close()

    def __enter__(self) -> "DataWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class DataReader:
    """Read a data archive written by :class:`DataWriter`; raises :class:`DataFileError`
    naming the file when it is not a complete one (``what`` says what it should be and the fix)."""

    def __init__(self, path: str | Path, what: str = "data file") -> None:
        self.path = Path(path)
        self.what = what
        try:
            self._npz = np.load(self.path, allow_pickle=False)
        except (OSError, EOFError, ValueError, zipfile.BadZipFile) as ex:
            raise DataFileError(f"'{self.path}' is not a {what} ({type(ex).__name__}: {ex})") from None
        if not isinstance(self._npz, np.lib.npyio.NpzFile):
            self.close()
            raise DataFileError(f"'{self.path}' is not a {what} (a single array, not an archive)")

    def _array(self, key: str) -> np.ndarray:
        try:
            return self._npz[key]
        except (KeyError, OSError, EOFError, ValueError, zipfile.BadZipFile) as ex:
            # ValueError: e.g. "Object arrays cannot be loaded when allow_pickle=False"
            raise DataFileError(f"'{self.path}' is not a complete {self.what}: member '{key}' "
                                f"({type(ex).__name__}: {ex})") from None

    def get(self, name: str) -> Any:
        """The value stored under ``name``."""
        raw = self._array(name)
        if raw.dtype != np.uint8 or raw.ndim != 1:
            raise DataFileError(f"'{self.path}' is not a {self.what}: member '{name}' is not a JSON document")
        try:
            doc = json.loads(raw.tobytes().decode("utf-8"))
        except (UnicodeDecodeError, ValueError) as ex:
            raise DataFileError(f"'{self.path}' is not a {self.what}: member '{name}' ({ex})") from None
        return self._decode(doc)

    def _decode(self, doc: Any) -> Any:
        if isinstance(doc, list):
            return [self._decode(v) for v in doc]
        if not isinstance(doc, dict):
            return doc
        if len(doc) != 1 or next(iter(doc)) not in TAGS:
            raise DataFileError(f"'{self.path}' is not a {self.what}: an untagged mapping")
        tag, body = next(iter(doc.items()))
        if tag == "__tuple__":
            return tuple(self._decode(v) for v in body)
        if tag == "__dict__":
            return {self._decode(k): self._decode(v) for k, v in body}
        if not isinstance(body, str):
            raise DataFileError(f"'{self.path}' is not a {self.what}: a bad array reference")
        array = self._array(body)
        return array if tag == "__array__" else array[()]

    def close(self) -> None:
        """Close the archive."""
        npz = getattr(self, "_npz", None)
        if npz is not None and hasattr(npz, "close"):
            npz.close()

    def __enter__(self) -> "DataReader":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
