"""RVR-LAAF Refocus: synthetic shallow depth of field for video strips (Blender extension).

This file only wires the parts together: operators (and their properties), then panels, and
the ``blender -c rvr ...`` command line. The engine, ``rvr_addon``, never imports bpy.
Imports are relative: Blender imports this package as ``bl_ext.<repository>.rvr_laaf``.
"""
from __future__ import annotations

import bpy

from . import operators, panels

_cli_handle = None


def _cli(argv: list[str]) -> int:
    """``blender -b -c rvr ...``: strip commands (``analyze``, and ``autofocus``/``render`` with
    ``--blend FILE``) run the Sequencer operators on a .blend (:mod:`.operators.cli`); every
    other command is the engine's ``rvr`` command line."""
    from .operators import cli as strip_cli
    from .rvr_addon import cli

    argv = list(argv)
    if strip_cli.wants_blender(argv):
        return strip_cli.run(argv)
    try:
        return cli.main(argv)
    except SystemExit as ex:  # argparse's --help / usage errors: an exit status, not Blender's exit
        return ex.code if isinstance(ex.code, int) else (0 if ex.code is None else 1)


def register() -> None:
    global _cli_handle
    operators.register()
    panels.register()
    if hasattr(bpy.utils, "register_cli_command"):  # Blender 4.2+
        _cli_handle = bpy.utils.register_cli_command("rvr", _cli)


def unregister() -> None:
    global _cli_handle
    if _cli_handle is not None:
        bpy.utils.unregister_cli_command(_cli_handle)
        _cli_handle = None
    panels.unregister()
    operators.unregister()
