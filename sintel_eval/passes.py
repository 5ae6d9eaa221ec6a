"""Cycles render passes of the harness (bpy): the pinhole "deep" pass (radiance, planar depth,
object index) and thin-lens DOF passes at a given focus distance and f-number.

One :class:`PassRenderer` per built scene. Each render goes to a multilayer EXR in a private
temporary folder, is read back with numpy and clamped to the scene's brightest emitted radiance
(no pixel can be brighter; OpenImageDenoise can overshoot on tiny very bright discs).
"""
from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rvr_addon.errors import OutputError

from .bpy_util import bpy, read_passes, set_image_settings, setup_render, working_space


def configure_cycles(scene, width: int, height: int, seed: int, denoise: bool, fps: int) -> dict:
    """Cycles settings of the harness (see :func:`bpy_util.setup_render`), tuned for speed on
    a small CPU: 1 diffuse + 1 glossy bounce (chrome still mirrors its glints), no light tree
    (few lights), OpenImageDenoise with the FAST prefilter (the ACCURATE one costs ~0.6 s a
    frame at 320x180). Returns the settings for the manifest."""
    denoiser = setup_render(scene, width, height, samples=16, seed=seed, denoise=denoise, fps=fps,
                            object_index=True)
    c = scene.cycles
    c.max_bounces = 3
    c.diffuse_bounces = 1
    c.glossy_bounces = 1
    c.transparent_max_bounces = 0
    c.use_light_tree = False
    if denoiser != "none":
        c.denoising_prefilter = "FAST"
    return {"engine": "CYCLES", "device": "CPU", "blender": bpy.app.version_string, "seed": int(seed),
            "denoiser": denoiser, "denoising_prefilter": c.denoising_prefilter if denoiser != "none" else None,
            "denoise_inputs": {"deep": "RGB_ALBEDO_NORMAL", "dof": "RGB"},
            "max_bounces": c.max_bounces, "diffuse_bounces": c.diffuse_bounces, "glossy_bounces": c.glossy_bounces,
            "adaptive_sampling": False, "light_tree": False, "pixel_filter": "BLACKMAN_HARRIS",
            "filter_width_px": float(c.filter_width), "view_transform": "Standard", "look": "None",
            "dither": 0.0, "scene_linear": working_space(), "sample_clamp_indirect": float(c.sample_clamp_indirect)}


@dataclass(frozen=True)
class LensSetting:
    """A render's lens: planar focus distance (m) and f-number; both None = pinhole."""

    focus_distance_m: float | None = None
    f_number: float | None = None

    @property
    def pinhole(self) -> bool:
        return self.f_number is None

    def key(self) -> tuple:
        """Identity for reusing a render within one frame (same lens -> same image)."""
        if self.pinhole:
            return ("pinhole",)
        return (round(float(self.focus_distance_m), 9), round(float(self.f_number), 6))


class PassRenderer:
    """Renders the posed frame of ``scene`` with ``camera``.

    samples_deep / samples_dof: Cycles samples of the pinhole pass and of the DOF passes;
    radiance_cap: (3,) per-channel upper bound of radiance. ``timings`` accumulates seconds
    per pass kind ("deep", "dof").
    """

    def __init__(self, scene, camera, samples_deep: int, samples_dof: int, radiance_cap: np.ndarray):
        self.scene = scene
        self.camera = camera
        self.samples_deep = int(samples_deep)
        self.samples_dof = int(samples_dof)
        self.cap = np.asarray(radiance_cap, dtype=np.float32)
        base = "/dev/shm" if Path("/dev/shm").is_dir() else None
        self._tmp = tempfile.TemporaryDirectory(prefix="rvr_harness_", dir=base)
        self._exr = Path(self._tmp.name) / "render.exr"
        self.timings: dict[str, float] = {"deep": 0.0, "dof": 0.0}
        self.counts: dict[str, int] = {"deep": 0, "dof": 0}
        set_image_settings(scene, "exr")

    def close(self) -> None:
        """Remove the temporary folder."""
        self._tmp.cleanup()

    def _render(self, samples: int, lens: LensSetting, data_passes: bool) -> dict[str, np.ndarray]:
        vl = self.scene.view_layers[0]
        vl.use_pass_z = data_passes
        vl.use_pass_object_index = data_passes
        cyc = self.scene.cycles
        cyc.samples = int(samples)
        if cyc.use_denoising:
            # The pinhole albedo/normal are clean guides; through a lens they are as noisy as the
            # image, so the DOF passes are denoised from the colour alone.
            cyc.denoising_input_passes = "RGB_ALBEDO_NORMAL" if data_passes else "RGB"
        dof = self.camera.data.dof
        dof.use_dof = not lens.pinhole
        if not lens.pinhole:
            dof.focus_object = None
            dof.focus_distance = float(lens.focus_distance_m)
            dof.aperture_fstop = float(lens.f_number)
        bpy.ops.render.render(write_still=False)
        result = bpy.data.images["Render Result"]
        try:
            result.save_render(str(self._exr), scene=self.scene)
        except RuntimeError as exc:
            raise OutputError(f"cannot save the render to '{self._exr}': {exc}; check free space in "
                              f"{self._exr.parent}") from exc
        passes = read_passes(self._exr, object_index=data_passes, depth=data_passes)
        passes["rgb"] = np.minimum(np.maximum(passes["rgb"], 0.0), self.cap)
        return passes

    def render_deep(self) -> dict[str, np.ndarray]:
        """Pinhole pass: {"rgb": (H, W, 3) linear radiance, "z": (H, W) planar depth m,
        "id": (H, W) object pass index}."""
        t0 = time.perf_counter()
        out = self._render(self.samples_deep, LensSetting(), data_passes=True)
        self.timings["deep"] += time.perf_counter() - t0
        self.counts["deep"] += 1
        return out

    def render_dof(self, lens: LensSetting, samples: int | None = None) -> np.ndarray:
        """Thin-lens pass: (H, W, 3) linear radiance focused at ``lens.focus_distance_m`` (planar)
        with f-number ``lens.f_number``."""
        if lens.pinhole:
            raise ValueError("render_dof needs a focus distance and an f-number")
        t0 = time.perf_counter()
        out = self._render(samples or self.samples_dof, lens, data_passes=False)["rgb"]
        self.timings["dof"] += time.perf_counter() - t0
        self.counts["dof"] += 1
        return out
