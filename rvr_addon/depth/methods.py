"""The ``--depth-method`` names (see :mod:`.system`), importable without NumPy: ``rvr estimate --help``,
``rvr batch --help`` and ``rvr refocus --help`` list them."""
from __future__ import annotations

METHODS = ("auto", "parallax", "people", "network", "external")
