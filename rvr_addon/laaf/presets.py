"""The names the LAAF command lines offer, importable without NumPy or the detectors (``rvr
autofocus --help``, ``rvr batch --help``, ``rvr refocus --help`` and the Blender panel list them):
the AI-assist presets (:mod:`.combine`), the pull profiles (:mod:`.puller`) and the names
``rvr eval-focus`` evaluates (:mod:`.evaluate`)."""
from __future__ import annotations

PRESETS: dict[str, tuple[str, ...]] = {
    "auto": ("speech", "face", "action", "saliency"),  # reads the clip, picks one of the others (.auto)
    "action": ("action", "saliency"),
    "conversation": ("speech", "face"),
    "faces": ("face",),
    "salient": ("saliency",),
    "learned": ("afnet",),  # AF-Net (rvr_addon/afnet): proposes NFTs itself, needs trained weights
}
"""Detector names of each AI-assist preset."""
AUTO = "auto"
"""The preset that reads the clip (speech? faces? motion?) and picks one of the others (:mod:`.auto`)."""
DEFAULT_PRESET = AUTO
"""The preset `rvr autofocus`, `rvr refocus`, `rvr batch` and Blender use when none is chosen."""

DECISION_VERSION = 2
"""Version of LAAF's decision: bump it when the same clip, depth and settings give another focus
decision, so what was reused by its settings (``rvr refocus``'s focus file, ``rvr batch``'s done
markers) is made again. 2 (2026-12-07): pulls, windows and detector rates in seconds, not frames."""

DEFAULT_CALM = 0.5
"""The default of the calm <-> responsive knob, 0..1 (:mod:`.calm`; ``rvr autofocus --calm``, Blender)."""

PROFILES = ("linear", "ease_in_out_cubic", "ease_in_out_sine", "critically_damped")
"""Focus-pull profiles (:func:`.puller.pull_weight`)."""

VARIANTS = {"learned-map": ("learned", {"afnet_speaker": False})}
"""Evaluation-only names of ``rvr eval-focus``: (preset, AutofocusSettings overrides)."""
EVAL_PRESETS = (*PRESETS, *VARIANTS)
