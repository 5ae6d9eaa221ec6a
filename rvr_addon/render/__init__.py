"""The forward renderers (model.py defines the model; fast.py the CPU path; device.py torch/CUDA).

Light on purpose (no numpy): the command-line parsers take the ``--device`` choices from here."""
from __future__ import annotations

DEVICES = ("auto", "cpu", "cuda")
"""Values of ``--device``: auto = CUDA when torch sees a GPU, else the fast CPU renderer."""
DEVICE_HELP = ("where to render: auto (default: the GPU when torch sees one, else the CPU), cpu (the fast CPU "
               "renderer), cuda (the GPU; an error without one)")
"""The ``--device`` help text every command shares."""
