"""A bpy-free stand-in for ``UILayout`` in smoke draws of the panels (tests/blender)."""
from __future__ import annotations

from typing import Any


class LayoutRecorder:
    """Records what a panel's ``draw()`` puts on the layout; returns itself for rows, columns, boxes.

    ``calls`` holds ``("prop", name)``, ``("operator", idname, icon)``, ``("list", listtype)``,
    ``("label", text)`` and ``("progress", factor)``. ``prop`` and ``template_list`` read the
    property, so a misspelled name fails.
    """

    def __init__(self) -> None:
        self.calls: list[tuple] = []
        self.use_property_split = False
        self.use_property_decorate = True

    def _sub(self, *_a: Any, **_k: Any) -> LayoutRecorder:
        return self

    row = column = box = split = _sub

    def prop(self, data: Any, name: str, **kw: Any) -> None:
        getattr(data, name)  # fails on a misspelled property
        self.calls.append(("prop", name))

    def operator(self, idname: str, **kw: Any) -> object:
        self.calls.append(("operator", idname, kw.get("icon")))
        return type("OpProps", (), {})()

    def template_list(self, listtype: str, list_id: str, data: Any, prop: str, active_data: Any, active_prop: str,
                      **kw: Any) -> None:
        getattr(data, prop), getattr(active_data, active_prop)
        self.calls.append(("list", listtype))

    def label(self, **kw: Any) -> None:
        self.calls.append(("label", kw.get("text")))

    def progress(self, **kw: Any) -> None:
        self.calls.append(("progress", kw.get("factor")))

    def separator(self, **kw: Any) -> None:
        pass
