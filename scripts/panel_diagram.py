"""docs/blender_panel.png: an annotated diagram of the Sequencer sidebar's Refocus tab.

    .venv/bin/python scripts/panel_diagram.py [-o docs/blender_panel.png]

Blender's UI cannot be drawn (or screenshotted) in background mode, so this draws a mock of it
from the panels' OWN ``draw()`` code: the add-on is registered in a bpy session, a movie strip
(a tiny testsrc2 clip made with imageio-ffmpeg's ffmpeg) is analysed, given two focus targets,
tracked and keyed; then every panel of the Refocus tab (found by its space, region and
category, ordered as Blender shows them) draws into :class:`TreeLayout`, a stand-in for
``UILayout`` that records the nesting (row / column / box / split) and, for each element, what
Blender would display (the RNA property's UI name and value, the operator's label and icon,
the target list drawn by the list's own ``draw_item``). The tree is then painted as a
Blender-like dark UI with numbered callouts and a legend. A control added to a panel appears
in the picture by itself; a new operator gets a callout with its own description.
"""
from __future__ import annotations

import argparse
import importlib
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any, Iterator

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "rvr_laaf"
CATEGORY = "Refocus"
CLIP_W, CLIP_H, CLIP_N, CLIP_FPS = 64, 36, 12, 24


# ----------------------------------------------------------------------------- the layout tree

@dataclass
class Node:
    """One element of a recorded layout: a container (``kind`` row/column/box/split/panel) with
    ``children``, or a leaf (prop/operator/label/list/progress/separator/other)."""

    kind: str
    text: str = ""  # what the element shows (a prop's or operator's text= override, else its name)
    name: str = ""  # a prop's RNA name, an operator's bl_label
    value: Any = None
    icon: str = ""
    ident: str = ""  # "RVR_PG_strip.aperture" for a prop, "rvr.analyze" for an operator, the UIList type
    children: list[Node] = field(default_factory=list)
    align: bool = False
    split: bool = False  # use_property_split when the element was added
    factor: float = 0.0
    emboss: bool = True
    enabled: bool = True
    prop_type: str = ""  # RNA type of a prop: BOOLEAN, INT, FLOAT, STRING, ENUM, ...
    subtype: str = ""
    description: str = ""
    rows: int = 0  # template_list: the rows it shows at least
    active: int = -1  # template_list: the active item

    def walk(self) -> Iterator[Node]:
        """This node and every node under it, depth first, in drawing order."""
        yield self
        for child in self.children:
            yield from child.walk()


def _enum_name(rna_prop: Any, value: Any) -> str:
    for item in rna_prop.enum_items:
        if item.identifier == value:
            return item.name
    return str(value)


def _format_number(rna_prop: Any, value: Any) -> str:
    import math

    if rna_prop.type == "INT":
        return str(int(value))
    if rna_prop.subtype == "ANGLE":
        return f"{math.degrees(value):.0f}\u00b0"
    text = f"{value:.{max(0, min(int(rna_prop.precision), 3))}f}"
    return text + (" %" if rna_prop.subtype == "PERCENTAGE" else "")


def display_value(data: Any, name: str) -> Any:
    """What Blender shows for ``data.<name>``: an enum's item name, a number at its precision, a
    tuple of those for a vector, the bool, the string."""
    rna_prop = data.bl_rna.properties[name]
    value = getattr(data, name)
    if rna_prop.type == "ENUM":
        if rna_prop.is_enum_flag:
            return ", ".join(_enum_name(rna_prop, v) for v in sorted(value))
        return _enum_name(rna_prop, value)
    if rna_prop.type in {"INT", "FLOAT"}:
        if getattr(rna_prop, "array_length", 0):
            return tuple(_format_number(rna_prop, v) for v in value)
        return _format_number(rna_prop, value)
    if rna_prop.type == "BOOLEAN":
        return bool(value)
    return value if isinstance(value, str) else str(value)


class _OpProps:
    """What ``layout.operator()`` returns: takes any property assignment (and records it)."""

    def __init__(self, node: Node) -> None:
        object.__setattr__(self, "_node", node)

    def __setattr__(self, name: str, value: Any) -> None:
        self._node.value = {**(self._node.value or {}), name: value}


class TreeLayout:
    """A stand-in for ``bpy.types.UILayout`` that records a tree of :class:`Node` (under ``node``).

    Sub-layouts inherit ``use_property_split`` when they are made, as in Blender; each prop
    records the flag of its layout when added. Unknown ``UILayout`` calls are recorded as
    ``other`` leaves instead of failing, so a panel using something new still draws.
    """

    def __init__(self, node: Node | None = None, context: Any = None, split: bool = False) -> None:
        self.node = node if node is not None else Node("column")
        self.context = context
        self.use_property_split = split
        self.use_property_decorate = True
        self.enabled = True
        self.active = True
        self.alert = False
        self.scale_x = self.scale_y = 1.0
        self.alignment = "EXPAND"

    # -- containers
    def _sub(self, kind: str, align: bool = False, factor: float = 0.0) -> TreeLayout:
        child = Node(kind, align=align, factor=factor, split=self.use_property_split)
        self.node.children.append(child)
        return TreeLayout(child, self.context, self.use_property_split)

    def row(self, align: bool = False, heading: str = "", **_kw: Any) -> TreeLayout:
        """A row node."""
        return self._sub("row", align)

    def column(self, align: bool = False, heading: str = "", **_kw: Any) -> TreeLayout:
        """A column node."""
        return self._sub("column", align)

    def box(self) -> TreeLayout:
        """A box node (a framed column)."""
        return self._sub("box")

    def split(self, factor: float = 0.0, align: bool = False) -> TreeLayout:
        """A split node: the first part ``factor`` of the width."""
        return self._sub("split", align, factor)

    def grid_flow(self, align: bool = False, **_kw: Any) -> TreeLayout:
        """A grid or column flow, recorded as a column."""
        return self._sub("column", align)

    column_flow = grid_flow

    def _leaf(self, node: Node) -> Node:
        node.split = self.use_property_split
        self.node.children.append(node)
        return node

    # -- elements
    def prop(self, data: Any, name: str, text: str | None = None, icon: str = "NONE", emboss: bool = True,
             **_kw: Any) -> None:
        """The RNA property's UI name (or ``text``) and its displayed value."""
        rna_prop = data.bl_rna.properties[name]  # KeyError on a misspelled property
        self._leaf(Node("prop", text=rna_prop.name if text is None else text, name=rna_prop.name,
                        value=display_value(data, name),
                        icon=icon, ident=f"{data.bl_rna.identifier}.{name}", emboss=emboss,
                        prop_type=rna_prop.type, subtype=rna_prop.subtype, description=rna_prop.description))

    def operator(self, idname: str, text: str | None = None, icon: str = "NONE", emboss: bool = True,
                 **_kw: Any) -> _OpProps:
        """The operator's ``bl_label`` (or ``text``), its icon and whether it polls true now."""
        import bpy

        module, _, fn = idname.partition(".")
        op = getattr(getattr(bpy.ops, module), fn)
        rna = op.get_rna_type()  # fails on an unknown idname
        try:
            enabled = bool(op.poll())
        except Exception:  # noqa: BLE001 - a poll that needs a real window: draw it enabled
            enabled = True
        node = self._leaf(Node("operator", text=rna.name if text is None else text, name=rna.name, icon=icon,
                               ident=idname,
                               emboss=emboss, enabled=enabled, description=rna.description))
        return _OpProps(node)

    def label(self, text: str = "", icon: str = "NONE", **_kw: Any) -> None:
        """A label: its text and icon."""
        self._leaf(Node("label", text=text, icon=icon, ident="label:" + (text.split(" ")[0] if text else "")))

    def progress(self, factor: float = 0.0, type: str = "BAR", text: str = "", **_kw: Any) -> None:  # noqa: A002
        """A progress bar: its fill (0..1) and text."""
        self._leaf(Node("progress", text=text, value=float(factor), ident="progress"))

    def separator(self, factor: float = 1.0, **_kw: Any) -> None:
        """Some space."""
        self._leaf(Node("separator", value=float(factor)))

    def separator_spacer(self) -> None:
        """A stretching space (recorded as no space)."""
        self._leaf(Node("separator", value=0.0))

    def template_list(self, listtype: str, list_id: str, data: Any, prop: str, active_data: Any, active_prop: str,
                      rows: int = 5, **_kw: Any) -> None:
        """The list, each item drawn by the UIList's own ``draw_item`` into a row node."""
        import bpy

        cls = getattr(bpy.types, listtype)
        items = getattr(data, prop)
        active = getattr(active_data, active_prop)
        node = self._leaf(Node("list", text=data.bl_rna.properties[prop].name, ident=listtype, rows=rows,
                               active=active))
        for index, item in enumerate(items):
            sub = TreeLayout(Node("row"), self.context)
            cls.draw_item(_Proxy(cls), self.context, sub, data, item, 0, active_data, active_prop, index)
            node.children.append(sub.node)

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):
            raise AttributeError(name)

        def other(*_a: Any, **kw: Any) -> TreeLayout:
            self._leaf(Node("other", text=kw.get("text") or name, ident=name))
            return self

        return other


class _Proxy:
    """Stands in for a panel or list instance: ``layout`` plus the class's own attributes."""

    def __init__(self, cls: type, layout: TreeLayout | None = None) -> None:
        self._cls = cls
        self.layout = layout

    def __getattr__(self, name: str) -> Any:
        value = getattr(self._cls, name)
        return value.__get__(self) if callable(value) and hasattr(value, "__get__") else value


# ----------------------------------------------------------------------------- panels

@dataclass
class PanelTree:
    """One panel as Blender shows it: its class, label, depth (0 = top level) and layout tree."""

    idname: str
    label: str
    depth: int
    root: Node


def tab_panels(category: str = CATEGORY) -> list[type]:
    """The registered Sequencer sidebar panels of ``category``, parents before their children,
    in Blender's order (``bl_order``, then registration order)."""
    import bpy

    found = [cls for cls in bpy.types.Panel.__subclasses__()
             if getattr(cls, "bl_space_type", "") == "SEQUENCE_EDITOR" and getattr(cls, "bl_region_type", "") == "UI"
             and getattr(cls, "bl_category", "") == category and getattr(cls, "is_registered", False)]
    order = {cls: i for i, cls in enumerate(found)}
    by_parent: dict[str, list[type]] = {}
    for cls in found:
        by_parent.setdefault(getattr(cls, "bl_parent_id", ""), []).append(cls)
    out: list[type] = []

    def add(parent: str) -> None:
        for cls in sorted(by_parent.get(parent, []), key=lambda c: (getattr(c, "bl_order", 0), order[c])):
            out.append(cls)
            add(getattr(cls, "bl_idname", cls.__name__))

    add("")  # a child of a panel outside the tab is shown nowhere here
    return out


def capture_panels(context: Any, category: str = CATEGORY) -> list[PanelTree]:
    """Draw every panel of the tab that polls true into a :class:`TreeLayout`; a child of a
    panel that is not shown is not shown either."""
    shown: dict[str, int] = {}
    out: list[PanelTree] = []
    for cls in tab_panels(category):
        idname = getattr(cls, "bl_idname", cls.__name__)
        parent = getattr(cls, "bl_parent_id", "")
        if parent and parent not in shown:
            continue
        if hasattr(cls, "poll") and not cls.poll(context):
            continue
        depth = shown[parent] + 1 if parent else 0
        shown[idname] = depth
        layout = TreeLayout(Node("panel", text=cls.bl_label, ident=idname), context)
        cls.draw(_Proxy(cls, layout), context)
        out.append(PanelTree(idname, cls.bl_label, depth, layout.node))
    return out


def capture_job_status(context: Any, module: ModuleType) -> Node:
    """The job status the Refocus panel draws while a job runs (``draw_job_status`` with a
    RUNNING job), restored to what it was afterwards."""
    wm = context.window_manager
    saved = (wm.rvr_job_status, wm.rvr_job_text, wm.rvr_job_progress)
    try:
        wm.rvr_job_status, wm.rvr_job_text, wm.rvr_job_progress = "RUNNING", "Analyze: frame 7/12 (58%)", 58.0
        layout = TreeLayout(Node("panel", text="While a job runs"), context)
        module.draw_job_status(layout, wm)
        return layout.node
    finally:
        wm.rvr_job_status, wm.rvr_job_text, wm.rvr_job_progress = saved


# ----------------------------------------------------------------------------- the scene

def load_addon() -> ModuleType:
    """The repository root imported as ``rvr_laaf`` (as Blender imports the extension)."""
    if PACKAGE in sys.modules:
        return sys.modules[PACKAGE]
    path = Path(tempfile.mkdtemp(prefix="rvr_addon_path_"))
    (path / PACKAGE).symlink_to(ROOT, target_is_directory=True)
    sys.path.insert(0, str(path))
    return importlib.import_module(PACKAGE)


def make_clip(path: Path) -> Path:
    """A 64x36, 12-frame clip at 24 fps: a white square moving over testsrc2 (something to track)."""
    import imageio_ffmpeg

    src = (f"testsrc2=size={CLIP_W}x{CLIP_H}:rate={CLIP_FPS}[bg];color=c=white:s=14x14:r={CLIP_FPS}[fg];"
           f"[bg][fg]overlay=x='4+{3 * CLIP_FPS}*t':y=10:shortest=1")
    subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-nostdin", "-v", "error", "-y", "-f", "lavfi",
                    "-i", src, "-frames:v", str(CLIP_N), "-c:v", "libx264", "-preset", "ultrafast",
                    "-pix_fmt", "yuv420p", "-g", "1", str(path)], check=True, capture_output=True)
    return path


def build_scene(work: Path, analyze: bool = True) -> Any:
    """A fresh file saved in ``work`` with the add-on registered (by the caller) and a typical
    state: movie strip 'interview' active, analysed (shipped estimator, when it works here), two
    focus targets (the second active), tracked, with focus keys; the playhead on a key.
    Returns the strip."""
    import bpy

    bpy.ops.wm.save_as_mainfile(filepath=str(work / "edit.blend"))
    scene = bpy.context.scene
    scene.render.fps = CLIP_FPS
    editor = scene.sequence_editor_create()
    strip = editor.strips.new_movie("interview", str(make_clip(work / "interview.mp4")), channel=2, frame_start=1)
    editor.active_strip = strip
    strip.select = True
    if analyze:
        try:
            bpy.ops.rvr.analyze("EXEC_DEFAULT")
        except RuntimeError as ex:  # no estimator weights here: the panel simply shows no cache
            print(f"not analysed: {ex}", file=sys.stderr)
    bpy.ops.rvr.add_focus_target(x=11, y=17, w=14, h=14, frame=1)
    bpy.ops.rvr.add_focus_target(x=40, y=20, w=10, h=10, frame=8)
    try:
        bpy.ops.rvr.track_targets("EXEC_DEFAULT")
    except RuntimeError as ex:
        print(f"not tracked: {ex}", file=sys.stderr)
    strip.rvr.nft_index = 1
    strip.rvr.preview_mode = "REFOCUS"
    scene.frame_set(1)  # on the first focus key: the key buttons show a key here
    return strip


def capture(analyze: bool = True) -> tuple[list[PanelTree], Node]:
    """Register the add-on in a fresh file, build the scene, capture the tab's panels and the
    running-job status; unregisters afterwards. Returns (panels, job status)."""
    import bpy

    addon = load_addon()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    addon.register()
    try:
        with tempfile.TemporaryDirectory(prefix="rvr_panel_") as tmp:
            build_scene(Path(tmp), analyze=analyze)
            panels = capture_panels(bpy.context)
            job = capture_job_status(bpy.context, addon.panels.vse)
            bpy.ops.wm.read_factory_settings(use_empty=True)  # let go of the files in tmp
    finally:
        addon.unregister()
    return panels, job


# ----------------------------------------------------------------------------- the legend

LEGEND: dict[str, str] = {
    "RVR_PG_strip.focus_disparity": "Focus: the disparity in focus; animate it to pull focus (\u25c6 keys this frame)",
    "RVR_PG_strip.aperture": "Aperture: blur strength, 0 = no blur; keyable like Focus",
    "RVR_PG_strip.aperture_shape": "Shape: bokeh Disk, Polygon (blades, rotation) or Anamorphic (squeeze)",
    "RVR_PG_strip.depth_path": "Disparity: your own disparity maps (optional, replace the estimate)",
    "RVR_PG_strip.hdr_path": "HDR: optional HDR exponent maps, one per frame",
    "RVR_PG_strip.depth_method": "Depth: where Analyze takes depth from (Auto fuses every cue)",
    "RVR_PG_strip.hfov_deg": "Horizontal FOV: the camera's field of view, 0 = a phone's (66\u00b0)",
    "rvr.analyze": "Analyze: depth + HDR for the strip's frames into the cache; Esc cancels",
    "label:Cache:": "Cache: the clip's cache Analyze wrote, reused next time",
    "label:Depth": "Depth line: the depth cues the cache holds, on how many frames",
    "RVR_PG_strip.preview_mode": "Preview: the Sequencer preview shows Refocused or Disparity",
    "RVR_PG_strip.show_targets": "Show Targets: tracked boxes and focus point over the preview",
    "RVR_PG_strip.render_format": "Format: H.264 movie with the source's sound, or PNG frames",
    "RVR_PG_strip.render_size": "Size: full resolution or a 50% / 25% proxy",
    "RVR_PG_strip.output_dir": "Output: folder of the render (// = next to the .blend)",
    "rvr.render_strip": "Render Refocused Strip: bakes it with its keys, adds '<strip> [RVR]'",
    "progress": "Job progress: \u2715 (or Esc) cancels; finished frames are kept",
    "RVR_UL_nfts": "Focus targets: clip frame, source, tracked frames; \u25cf = kept",
    "rvr.add_focus_target": "Add Focus Target: drag a box around the subject in the preview",
    "rvr.remove_focus_target": "Remove Focus Target: deletes the active target",
    "rvr.jump_to_target": "Jump: move the playhead to the active target's frame",
    "RVR_PG_nft.frame": "Active target: its frame and box; Keep = Auto Focus leaves it alone",
    "RVR_PG_nft.pull_frames": "Pull / Lead of the target: its own (0 / -1 = the strip's defaults)",
    "RVR_PG_strip.pull_frames": "Pull / Lead: a pull's frames, landing this many before the target",
    "RVR_PG_strip.pull_profile": "Profile: how the focus moves during a pull",
    "RVR_PG_strip.hold_frames": "Hold: keep a lost subject's focus this long before moving on",
    "rvr.track_targets": "Track: follows every target through the clip, writes focus keys",
    "RVR_PG_strip.autofocus_preset": "Preset: what Auto Focus follows (the presets table above)",
    "RVR_PG_strip.lookahead_s": "Look-Ahead: how far ahead a pull may start (0 = like a camera)",
    "rvr.auto_focus": "Auto Focus: finds targets, writes focus keys; kept targets stay",
}
NO_CALLOUT = {"rvr.keyframe_toggle", "rvr.cancel_job"}  # explained with the property it keys, the progress


def legend_line(node: Node) -> str | None:
    """The legend's line for a node, or None when it gets no callout: the hand-written line,
    else (an operator added since) its label and the first sentence of its description."""
    if node.ident in LEGEND:
        return LEGEND[node.ident]
    if node.kind == "operator" and node.ident not in NO_CALLOUT:
        first = node.description.split(". ")[0].rstrip(".")
        return f"{node.name or node.ident}: {first}" if first else node.name or node.ident
    return None


# ----------------------------------------------------------------------------- painting

BG = (40, 40, 40)
REGION = (48, 48, 48)
PANEL = (61, 61, 61)
HEADER = (66, 66, 66)
SUBPANEL = (56, 56, 56)
BOX = (52, 52, 52)
BUTTON = (84, 84, 84)
FIELD = (34, 34, 34)
MENU = (40, 40, 40)
OUTLINE = (30, 30, 30)
TEXT = (230, 230, 230)
LABEL = (190, 190, 190)
DIM = (140, 140, 140)
BLUE = (71, 114, 179)
ACTIVE_ROW = (51, 77, 128)
KEY = (235, 200, 60)
BADGE = (255, 140, 30)

UNIT = 26  # one row of widgets (Blender's UI unit at ~1.3x)
GAP = 3
PAD = 10
PANEL_W = 440

ICONS = {
    "ADD": "+", "REMOVE": "\u2212", "TIME": "\u25f7", "CANCEL": "\u2715", "CHECKMARK": "\u2713", "INFO": "\u2139",
    "VIEW_CAMERA": "\u25c9", "RENDER_ANIMATION": "\u25b6", "TRACKER": "\u2295", "VIEWZOOM": "\u26b2",
    "PINNED": "\u25cf", "UNPINNED": "\u25cb", "DECORATE_KEYFRAME": "\u25c6", "DECORATE_ANIMATE": "\u25c7",
    "DECORATE": "\u00b7", "ERROR": "!", "FILE_REFRESH": "\u27f3",
}


def _font(size: int, bold: bool = False) -> Any:
    from PIL import ImageFont
    import matplotlib

    name = "DejaVuSans-Bold.ttf" if bold else "DejaVuSans.ttf"
    return ImageFont.truetype(str(Path(matplotlib.__file__).parent / "mpl-data" / "fonts" / "ttf" / name), size)


@dataclass
class Placed:
    """A leaf (or box/list) with its rectangle (x0, y0, x1, y1) on the picture."""

    node: Node
    rect: tuple[int, int, int, int]


def _icon_only(node: Node) -> bool:
    return node.kind in {"operator", "label"} and not node.text and node.icon not in {"", "NONE"}


def fixed_width(node: Node) -> int | None:
    """The width of an element that does not stretch in a row (icon-only buttons), else None."""
    if _icon_only(node):
        return UNIT
    if node.kind in {"column", "box"} and node.children:
        widths = [fixed_width(c) for c in node.children]
        return max(widths) if all(w is not None for w in widths) else None  # type: ignore[type-var]
    if node.kind == "row" and node.children:
        widths = [fixed_width(c) for c in node.children]
        return sum(widths) if all(w is not None for w in widths) else None  # type: ignore[arg-type]
    return None


def leaf_height(node: Node) -> int:
    """Height of a leaf: one unit, a vector prop one per component (split), a list its rows."""
    if node.kind == "separator":
        return int(UNIT * 0.4 * max(node.value, 0.5))
    if node.kind == "prop" and isinstance(node.value, tuple) and node.split:
        return UNIT * len(node.value)
    if node.kind == "list":
        return UNIT * max(node.rows, len(node.children)) + 16 + 4
    return UNIT


def place(node: Node, x: int, y: int, w: int, out: list[Placed]) -> int:
    """Lay ``node`` out at (x, y), ``w`` wide, appending leaves (and boxes) to ``out``; returns its height."""
    if node.kind in {"column", "panel", "box"}:
        inner_x, inner_w, top = x, w, y
        if node.kind == "box":
            box = Placed(node, (x, y, x + w, y))
            out.append(box)
            inner_x, inner_w, top = x + 6, w - 12, y + 6
        cy = top
        for i, child in enumerate(node.children):
            if i:
                cy += 1 if node.align else GAP
            cy += place(child, inner_x, cy, inner_w, out)
        if node.kind == "box":
            cy += 6
            box.rect = (x, y, x + w, cy)
        return cy - y
    if node.kind in {"row", "split"}:
        kids = node.children
        if not kids:
            return 0
        gap = 1 if node.align else 4
        fixed = [fixed_width(c) for c in kids]
        free = w - sum(f for f in fixed if f is not None) - gap * (len(kids) - 1)
        flexible = [i for i, f in enumerate(fixed) if f is None]
        widths: list[int] = []
        for i, f in enumerate(fixed):
            if f is not None:
                widths.append(f)
            elif node.kind == "split" and node.factor > 0 and len(flexible) > 1 and i == flexible[0]:
                widths.append(int(free * node.factor))
            elif node.kind == "split" and node.factor > 0 and len(flexible) > 1:
                widths.append(int(free * (1 - node.factor) / (len(flexible) - 1)))
            else:
                widths.append(free // max(len(flexible), 1))
        cx, height = x, 0
        for child, cw in zip(kids, widths):
            height = max(height, place(child, cx, y, cw, out))
            cx += cw + gap
        return height
    height = leaf_height(node)
    out.append(Placed(node, (x, y, x + w, y + height)))
    return height


class Painter:
    """Paints placed nodes as Blender's dark theme would (roughly)."""

    def __init__(self, image: Any) -> None:
        from PIL import ImageDraw

        self.draw = ImageDraw.Draw(image)
        self.font = _font(14)
        self.small = _font(12)
        self.bold = _font(14, bold=True)
        self.glyph = _font(15)

    def text(self, xy: tuple[float, float], text: str, fill: tuple = TEXT, anchor: str = "lm", font: Any = None,
             max_w: int | None = None) -> None:
        """Text at ``xy`` (PIL anchor), cut with an ellipsis beyond ``max_w`` px."""
        font = font or self.font
        if max_w is not None and font.getlength(text) > max_w:
            while text and font.getlength(text + "\u2026") > max_w:
                text = text[:-1]
            text += "\u2026"
        self.draw.text(xy, text, fill=fill, font=font, anchor=anchor)

    def icon(self, cx: float, cy: float, name: str, fill: tuple = TEXT) -> None:
        """A glyph standing in for a Blender icon, centred at (cx, cy)."""
        glyph = ICONS.get(name, "\u25a6")
        color = KEY if name == "DECORATE_KEYFRAME" else fill
        self.draw.text((cx, cy), glyph, fill=color, font=self.glyph, anchor="mm")

    def button(self, rect: tuple[int, int, int, int], fill: tuple, radius: int = 5) -> None:
        """A rounded widget background."""
        x0, y0, x1, y1 = rect
        self.draw.rounded_rectangle((x0, y0 + 1, x1, y1 - 1), radius=radius, fill=fill, outline=OUTLINE)

    def folder(self, x: float, y: float) -> None:
        """The file browser icon of a path field."""
        d = self.draw
        d.polygon([(x - 7, y - 4), (x - 2, y - 4), (x, y - 2), (x + 7, y - 2), (x + 7, y + 5), (x - 7, y + 5)],
                  outline=TEXT)

    def leaf(self, p: Placed) -> None:
        """Paint one placed element."""
        n, (x0, y0, x1, y1) = p.node, p.rect
        cy = (y0 + y1) / 2
        if n.kind == "box":
            self.draw.rounded_rectangle(p.rect, radius=6, fill=BOX, outline=(72, 72, 72))
        elif n.kind == "separator":
            return
        elif n.kind == "label":
            tx = x0 + 4
            if n.icon not in {"", "NONE"}:
                self.icon(x0 + 12 if n.text else (x0 + x1) / 2, cy, n.icon, LABEL)
                tx = x0 + 26
            if n.text:
                self.text((tx, cy), n.text, LABEL, max_w=x1 - tx - 2)
        elif n.kind == "operator":
            fg = TEXT if n.enabled else DIM
            if n.emboss:
                self.button(p.rect, BUTTON if n.enabled else (70, 70, 70))
            has_icon = n.icon not in {"", "NONE"}
            if not n.text:
                self.icon((x0 + x1) / 2, cy, n.icon, fg)
                return
            width = self.font.getlength(n.text) + (22 if has_icon else 0)
            tx = (x0 + x1 - width) / 2
            if has_icon:
                self.icon(tx + 8, cy, n.icon, fg)
                tx += 22
            self.text((tx, cy), n.text, fg, max_w=x1 - tx - 4)
        elif n.kind == "progress":
            self.button(p.rect, FIELD, radius=4)
            fill_x = x0 + int((x1 - x0) * min(max(n.value, 0.0), 1.0))
            if fill_x > x0 + 4:
                self.draw.rounded_rectangle((x0, y0 + 1, fill_x, y1 - 1), radius=4, fill=BLUE)
            self.text(((x0 + x1) / 2, cy), n.text, TEXT, anchor="mm", max_w=x1 - x0 - 8)
        elif n.kind == "list":
            self.list(p)
        elif n.kind == "prop":
            self.prop(p)
        else:
            self.button(p.rect, FIELD)
            self.text((x0 + 6, cy), f"[{n.text}]", DIM, max_w=x1 - x0 - 8)

    def list(self, p: Placed) -> None:
        """A UIList: its item rows (the active one highlighted), the filter toggle and the grip."""
        n, (x0, y0, x1, y1) = p.node, p.rect
        self.draw.rounded_rectangle((x0, y0 + 1, x1, y1 - 1), radius=5, fill=FIELD, outline=OUTLINE)
        for i, row in enumerate(n.children):
            ry = y0 + 2 + i * UNIT
            if i == n.active:
                self.draw.rectangle((x0 + 2, ry, x1 - 2, ry + UNIT - 1), fill=ACTIVE_ROW)
            placed: list[Placed] = []
            place(row, x0 + 4, ry, x1 - x0 - 8, placed)
            for q in placed:
                self.leaf(q)
        gy = y1 - 10
        self.draw.text((x0 + 10, gy), "\u25b8", fill=DIM, font=self.small, anchor="mm")
        self.draw.text(((x0 + x1) / 2, gy), "\u2237", fill=DIM, font=self.small, anchor="mm")

    def prop(self, p: Placed) -> None:
        """A property: label on the left when split, then its checkbox, menu, field(s) or path."""
        n, (x0, y0, x1, y1) = p.node, p.rect
        cy0 = y0 + UNIT / 2
        if n.split:
            label_w = int((x1 - x0) * 0.4)
            wx0 = x0 + label_w + 6
            if n.prop_type != "BOOLEAN" and n.text:
                self.text((x0 + label_w, cy0), n.text, LABEL, anchor="rm", max_w=label_w - 4)
        else:
            wx0 = x0
        if n.prop_type == "BOOLEAN":
            box = (wx0 + 2, cy0 - 7, wx0 + 16, cy0 + 7)
            self.draw.rounded_rectangle(box, radius=3, fill=BLUE if n.value else BUTTON, outline=OUTLINE)
            if n.value:
                self.draw.text(((box[0] + box[2]) / 2, cy0), "\u2713", fill=TEXT, font=self.small, anchor="mm")
            self.text((wx0 + 24, cy0), n.text, TEXT, max_w=x1 - wx0 - 26)
            return
        if isinstance(n.value, tuple):
            if n.split:
                for i, v in enumerate(n.value):
                    r = (wx0, y0 + i * UNIT, x1, y0 + (i + 1) * UNIT)
                    self.button(r, BUTTON, radius=4)
                    self.text(((wx0 + x1) / 2, (r[1] + r[3]) / 2), v, TEXT, anchor="mm")
            else:
                step = (x1 - x0) / len(n.value)
                for i, v in enumerate(n.value):
                    r = (int(x0 + i * step), y0, int(x0 + (i + 1) * step) - 1, y1)
                    self.button(r, BUTTON, radius=4)
                    self.text(((r[0] + r[2]) / 2, (y0 + y1) / 2), v, TEXT, anchor="mm")
            return
        r = (wx0, y0, x1, y1)
        cy = (y0 + y1) / 2
        if n.prop_type == "ENUM":
            self.button(r, MENU)
            self.text((wx0 + 8, cy), str(n.value), TEXT, max_w=x1 - wx0 - 28)
            self.draw.text((x1 - 12, cy), "\u25be", fill=LABEL, font=self.small, anchor="mm")
        elif n.prop_type == "STRING":
            path = n.subtype in {"FILE_PATH", "DIR_PATH"}
            self.button((wx0, y0, x1 - (UNIT + 1 if path else 0), y1), FIELD, radius=4)
            self.text((wx0 + 7, cy), str(n.value), TEXT, max_w=x1 - wx0 - 12 - (UNIT if path else 0))
            if path:
                self.button((x1 - UNIT, y0, x1, y1), BUTTON, radius=4)
                self.folder(x1 - UNIT / 2, cy)
        else:
            self.button(r, BUTTON)
            if n.split:
                self.text(((wx0 + x1) / 2, cy), str(n.value), TEXT, anchor="mm")
            else:
                self.text((wx0 + 8, cy), n.text, TEXT, max_w=(x1 - wx0) // 2)
                self.text((x1 - 8, cy), str(n.value), TEXT, anchor="rm")

    def badge(self, x: float, y: float, number: int) -> None:
        """A numbered callout circle."""
        r = 11
        self.draw.ellipse((x - r, y - r, x + r, y + r), fill=BADGE, outline=(40, 20, 0))
        self.draw.text((x, y + 0.5), str(number), fill=(20, 20, 20), font=_font(12, bold=True), anchor="mm")


def callouts(placed: list[Placed]) -> list[tuple[float, int, str]]:
    """(y, x where the row's last element ends, legend line) of every element with a legend
    line, top to bottom (a list's callout points at its grip row, below its side buttons)."""
    marks: list[tuple[float, int, str]] = []
    for p in placed:
        line = legend_line(p.node)
        if line is None or p.node.kind == "box":
            continue
        x0, y0, x1, y1 = p.rect
        cy = y1 - 10 if p.node.kind == "list" else y0 + min(UNIT, y1 - y0) / 2
        end = max([q.rect[2] for q in placed if q.node.kind != "box" and q.rect[1] <= cy <= q.rect[3]] + [x1])
        marks.append((cy, end, line))
    return sorted(marks, key=lambda m: m[0])


def paint(panels: list[PanelTree], job: Node | None, path: Path, title: str = "") -> Path:
    """Paint the panels (and the running-job status) with numbered callouts and a legend into ``path``."""
    from PIL import Image, ImageDraw

    placed: list[Placed] = []
    headers: list[tuple[int, int, int, str, int]] = []  # x, y, width, label, depth
    frames: list[tuple[int, int, int, int, int]] = []  # x0, y0, x1, y1, depth
    x0, y = 24, 64
    open_stack: list[tuple[int, int]] = []  # (depth, index in frames) of panels still open

    def close_to(depth: int, bottom: int) -> None:
        while open_stack and open_stack[-1][0] >= depth:
            _, idx = open_stack.pop()
            f = frames[idx]
            frames[idx] = (f[0], f[1], f[2], bottom, f[4])

    for i, panel in enumerate(panels):
        close_to(panel.depth, y)
        y += (2 if panel.depth else 8) if i else 0
        indent = 8 * panel.depth
        px, pw = x0 + indent, PANEL_W - 2 * indent
        frames.append((px, y, px + pw, y, panel.depth))
        open_stack.append((panel.depth, len(frames) - 1))
        headers.append((px, y, pw, panel.label, panel.depth))
        y += 30 + 6
        y += place(panel.root, px + PAD, y, pw - 2 * PAD, placed)
        y += PAD
    close_to(0, y)
    bottom_panels = y
    job_top = 0
    if job is not None:
        job_top = y + 40
        y = job_top + 26 + place(job, x0 + PAD, job_top + 26, PANEL_W - 2 * PAD, placed) + PAD

    marks = callouts(placed)
    lines = [line for _, _, line in marks]
    legend_x = x0 + PANEL_W + 40 + 36
    legend_step = max(26, min(34, (bottom_panels - 90) // max(len(lines), 1)))
    height = max(y + 40, 64 + len(lines) * legend_step + 60)
    width = legend_x + 610
    image = Image.new("RGB", (width, height), BG)
    paint_ = Painter(image)
    d = paint_.draw
    d.rectangle((x0 - 12, 48, x0 + PANEL_W + 30, bottom_panels + 12), fill=REGION)
    for fx0, fy0, fx1, fy1, depth in frames:
        d.rounded_rectangle((fx0, fy0, fx1, fy1), radius=6, fill=PANEL if depth == 0 else SUBPANEL,
                            outline=(34, 34, 34))
    for hx, hy, hw, label, depth in headers:
        d.rounded_rectangle((hx, hy, hx + hw, hy + 30), radius=6, fill=HEADER if depth == 0 else PANEL)
        d.text((hx + 14, hy + 15), "\u25be", fill=LABEL, font=paint_.small, anchor="mm")
        paint_.text((hx + 28, hy + 15), label, TEXT, font=paint_.bold if depth == 0 else paint_.font)
    if job is not None:
        d.rounded_rectangle((x0 - 12, job_top, x0 + PANEL_W + 30, y + 8), radius=6, fill=REGION)
        paint_.text((x0, job_top + 14), "While a job runs, the bottom of the Refocus panel shows:", DIM,
                    font=paint_.small)
    for p in placed:
        paint_.leaf(p)
    gutter = x0 + PANEL_W + 40 + 8
    badges: list[tuple[float, float]] = []
    for cy, end, _ in marks:  # leader lines from the row's last element to a badge in the gutter
        by = max(cy, badges[-1][1] + 24) if badges else cy  # badges at least 24 px apart
        d.line([(end + 3, cy), (gutter - 28, cy), (gutter - 11, by)], fill=BADGE, width=1)
        badges.append((gutter, by))
    # the tab strip at the sidebar's right edge
    tx = x0 + PANEL_W + 6
    d.rounded_rectangle((tx, 60, tx + 22, 160), radius=4, fill=PANEL)
    tab = Image.new("RGBA", (100, 22), (0, 0, 0, 0))
    ImageDraw.Draw(tab).text((50, 11), CATEGORY, fill=TEXT, font=paint_.font, anchor="mm")
    image.paste(tab.rotate(-90, expand=True), (tx, 60), tab.rotate(-90, expand=True))
    for number, (bx, by) in enumerate(badges, 1):
        paint_.badge(bx, by, number)
    ly = 64 + 12
    paint_.text((legend_x, 58 - 28), "What each control does", TEXT, font=_font(16, bold=True))
    for i, line in enumerate(lines, 1):
        paint_.badge(legend_x + 12, ly, i)
        name, sep, rest = line.partition(": ")
        if sep:
            paint_.text((legend_x + 32, ly), name + ":", TEXT, font=paint_.bold)
            paint_.text((legend_x + 32 + paint_.bold.getlength(name + ": "), ly), rest, LABEL,
                        max_w=width - legend_x - 40 - int(paint_.bold.getlength(name + ": ")))
        else:
            paint_.text((legend_x + 32, ly), line, LABEL, max_w=width - legend_x - 40)
        ly += legend_step
    paint_.text((x0 - 12, 26), title or "Video Sequencer > Sidebar (N) > Refocus", TEXT, font=_font(16, bold=True))
    paint_.text((x0 - 12, height - 18), "Drawn by scripts/panel_diagram.py from the panels' own draw() code "
                "(Blender's UI cannot be screenshotted headless).", DIM, font=paint_.small)
    path.parent.mkdir(parents=True, exist_ok=True)
    # 128 colours hold the flat UI and its anti-aliased text: a third of the file
    image.quantize(colors=128, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(path, optimize=True)
    return path


def main() -> int:
    """Capture the Refocus tab in a bpy session and paint docs/blender_panel.png."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-o", "--output", type=Path, default=ROOT / "docs" / "blender_panel.png")
    ap.add_argument("--no-analyze", action="store_true", help="skip Analyze (the panel then shows no cache)")
    args = ap.parse_args()
    panels, job = capture(analyze=not args.no_analyze)
    if not panels:
        raise SystemExit("no panel of the Refocus tab drew")
    print(f"wrote {paint(panels, job, args.output)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
