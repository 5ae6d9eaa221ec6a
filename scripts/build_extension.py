#!/usr/bin/env python3
"""Build the installable Blender extension zip: ``dist/rvr_laaf-<version>.zip``, or with
``--with-torch`` the full one, ``dist/rvr_laaf-<version>-full.zip``.

Runs Blender's own extension builder (``blender --command extension build``; here its script
``blender_ext.py`` from the bpy module, so no Blender executable is needed), which validates
``blender_manifest.toml`` (permissions, the wheels it lists, the build excludes) and packs the
extension.

Two builds, same extension id and version (installing one replaces the other):

* default (165.6 MB): the wheels blender_manifest.toml lists, the binary dependencies Blender
  does not ship (OpenCV-contrib, OpenEXR, imageio-ffmpeg with its ffmpeg, tqdm; mediapipe
  without its unused models, absl-py, attrs, flatbuffers, protobuf for the people depth cue;
  onnxruntime without its C API library and tools, which runs the estimator and AF-Net from their
  ONNX exports; webrtcvad for the Conversation preset). Analyze, Track, every Auto Focus preset
  and Render run without torch (tests/blender/test_vse_install.py). CI builds this one.
* ``--with-torch`` (about 365 MB): also torch 2.13.0 CPU and its dependencies (the files
  scripts/torch_wheels.txt lists), for running one's own ``.pt`` weights in Blender.
  Blender's builder reads the wheel list from the manifest of the source folder, so this
  build stages a copy of the extension with that list extended and builds from the copy;
  the repository's manifest keeps the light list.

The wheels must be in ./wheels first: ``scripts/fetch_wheels.sh`` (``--with-torch`` for the
full build). ``--dry-run`` checks them and prints the wheel list without building.

Usage: .venv/bin/python scripts/build_extension.py [--with-torch] [--dry-run] [--output-dir dist]
       (prints the zip path)
"""
from __future__ import annotations

import argparse
import fnmatch
import importlib.util
import os
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MANIFEST = "blender_manifest.toml"
TORCH_LIST = Path("scripts") / "torch_wheels.txt"
FULL_SUFFIX = "-full"


def blender_ext_script() -> Path:
    """``blender_ext.py`` (the extension CLI) shipped inside the installed bpy module."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or spec.origin is None:
        raise SystemExit("bpy is not installed in this Python; run scripts/setup.sh (or use .venv/bin/python)")
    found = sorted(Path(spec.origin).parent.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not found:
        raise SystemExit(f"blender_ext.py not found under {Path(spec.origin).parent}")
    return found[-1]


def read_manifest(root: Path = ROOT) -> dict:
    """The parsed blender_manifest.toml of root."""
    return tomllib.loads((root / MANIFEST).read_text())


def torch_wheels(root: Path = ROOT) -> list[str]:
    """The full build's extra wheels (scripts/torch_wheels.txt) as manifest paths ``./wheels/...``."""
    listing = root / TORCH_LIST
    if not listing.is_file():
        raise SystemExit(f"{listing} not found: it lists the torch wheels of the full build")
    names = [ln.strip() for ln in listing.read_text().splitlines()]
    return [f"./wheels/{n}" for n in names if n and not n.startswith("#")]


def wheel_list(root: Path = ROOT, with_torch: bool = False) -> list[str]:
    """The wheels the built manifest lists: the manifest's own, plus the torch ones if asked."""
    light = list(read_manifest(root).get("wheels", []))
    return light + [w for w in torch_wheels(root) if w not in light] if with_torch else light


def missing_wheels(root: Path = ROOT, with_torch: bool = False) -> list[str]:
    """Wheels the build would list that are not on disk."""
    return [w for w in wheel_list(root, with_torch) if not (root / w).is_file()]


def check_wheels(root: Path = ROOT, with_torch: bool = False) -> list[str]:
    """wheel_list(), or SystemExit naming the missing files and the command that fetches them."""
    missing = missing_wheels(root, with_torch)
    if missing:
        fix = "scripts/fetch_wheels.sh --with-torch" if with_torch else "scripts/fetch_wheels.sh"
        raise SystemExit(f"missing wheels in {root / 'wheels'}: {', '.join(Path(w).name for w in missing)}; "
                         f"run {fix} first")
    return wheel_list(root, with_torch)


def zip_path(output_dir: Path, root: Path = ROOT, with_torch: bool = False) -> Path:
    """``<id>-<version>.zip``, or ``<id>-<version>-full.zip`` for the build with torch."""
    manifest = read_manifest(root)
    return output_dir / f"{manifest['id']}-{manifest['version']}{FULL_SUFFIX if with_torch else ''}.zip"


def manifest_with_wheels(text: str, wheels: list[str]) -> str:
    """The manifest text with its top-level ``wheels = [...]`` array replaced by wheels."""
    body = "".join(f'  "{w}",\n' for w in wheels)
    new, n = re.subn(r"^wheels = \[.*?^\]", lambda _: f"wheels = [\n{body}]", text, count=1, flags=re.M | re.S)
    if n != 1:
        raise SystemExit(f"no top-level 'wheels = [...]' array in {MANIFEST}; the full build rewrites it")
    return new


def top_level_excluded(root: Path) -> set[str]:
    """Top-level names of root that the manifest's ``paths_exclude_pattern`` excludes (not worth
    staging; Blender's builder applies the full patterns to the staged copy anyway)."""
    patterns = [p.strip("/") for p in read_manifest(root).get("build", {}).get("paths_exclude_pattern", [])]
    return {e.name for e in root.iterdir() if any(fnmatch.fnmatch(e.name, p) for p in patterns if "/" not in p)}


def link_or_copy(src: Path, dst: Path) -> None:
    """Hard link src to dst (no 200 MB copy), copying when they are on different file systems."""
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def stage(root: Path, dest: Path, wheels: list[str]) -> None:
    """Copy the extension's source from root to dest (without excluded top-level entries and
    ./wheels), link the given wheels into dest/wheels and write the manifest listing them."""
    skip = top_level_excluded(root) | {"wheels", MANIFEST}
    dest.mkdir(parents=True, exist_ok=True)
    for entry in sorted(root.iterdir()):
        if entry.name in skip or dest.resolve().is_relative_to(entry.resolve()):
            continue
        if entry.is_dir() and not entry.is_symlink():
            shutil.copytree(entry, dest / entry.name, symlinks=True)
        else:
            shutil.copy2(entry, dest / entry.name, follow_symlinks=False)
    (dest / "wheels").mkdir()
    for w in wheels:
        link_or_copy(root / w, dest / w)
    (dest / MANIFEST).write_text(manifest_with_wheels((root / MANIFEST).read_text(), wheels))


def run_builder(source: Path, out: Path) -> Path:
    """Blender's extension builder: source folder -> zip out. SystemExit with its output on failure."""
    cmd = [sys.executable, str(blender_ext_script()), "build", "--source-dir", str(source),
           "--output-filepath", str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0 or not out.is_file():
        raise SystemExit(f"building the extension failed:\n{done.stdout}\n{done.stderr}")
    return out


def build(output_dir: Path, root: Path = ROOT, with_torch: bool = False) -> Path:
    """Build the zip into output_dir; returns its path. SystemExit with the fix on failure."""
    wheels = check_wheels(root, with_torch)
    output_dir.mkdir(parents=True, exist_ok=True)
    out = zip_path(output_dir, root, with_torch)
    if not with_torch:
        return run_builder(root, out)
    with tempfile.TemporaryDirectory(prefix=".stage-", dir=output_dir) as tmp:
        staged = Path(tmp) / read_manifest(root)["id"]
        stage(root, staged, wheels)
        return run_builder(staged, out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output-dir", type=Path, default=ROOT / "dist")
    parser.add_argument("--with-torch", action="store_true",
                        help="the full zip: also torch 2.13.0 CPU and its dependencies (scripts/torch_wheels.txt)")
    parser.add_argument("--dry-run", action="store_true",
                        help="check the wheels and print the zip path and the manifest's wheel list; build nothing")
    parser.add_argument("--source-dir", type=Path, default=ROOT, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.dry_run:
        wheels = check_wheels(args.source_dir, args.with_torch)
        print("\n".join([str(zip_path(args.output_dir, args.source_dir, args.with_torch)), *wheels]))
        return
    print(build(args.output_dir, args.source_dir, args.with_torch))


if __name__ == "__main__":
    main()
