"""RVR-LAAF engine: refocusable video rendering and look-ahead autofocus (no bpy here)."""
from __future__ import annotations

__version__ = "0.1.0"
