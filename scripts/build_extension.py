#!/usr/bin/env python3
"""Build the installable Blender extension zip: ``dist/rvr_laaf-<version>.zip``.

Runs Blender's own extension builder (``blender --command extension build``; here its script
``blender_ext.py`` from the bpy module, so no Blender executable is needed), which validates
``blender_manifest.toml`` (permissions, the wheels it lists, the build excludes) and packs the
extension. The wheels must be in ./wheels first: ``scripts/fetch_wheels.sh``.

The zip bundles the binary dependencies Blender does not ship (OpenCV-contrib, OpenEXR,
imageio-ffmpeg with its ffmpeg, tqdm). torch (the estimator, ~200 MB as a CPU wheel) is not
bundled: Analyze with estimator weights needs torch importable in Blender's Python (e.g.
``blender --python-use-system-env`` with a venv holding requirements.txt, or pip into
Blender's Python); depth from elsewhere, Track, Auto Focus and Render do not need it.

Usage: .venv/bin/python scripts/build_extension.py [--output-dir dist]   (prints the zip path)
"""
from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def blender_ext_script() -> Path:
    """``blender_ext.py`` (the extension CLI) shipped inside the installed bpy module."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or spec.origin is None:
        raise SystemExit("bpy is not installed in this Python; run scripts/setup.sh (or use .venv/bin/python)")
    found = sorted(Path(spec.origin).parent.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not found:
        raise SystemExit(f"blender_ext.py not found under {Path(spec.origin).parent}")
    return found[-1]


def missing_wheels(root: Path = ROOT) -> list[str]:
    """Wheels the manifest lists that are not on disk."""
    manifest = tomllib.loads((root / "blender_manifest.toml").read_text())
    return [w for w in manifest.get("wheels", []) if not (root / w).is_file()]


def build(output_dir: Path, root: Path = ROOT) -> Path:
    """Build the zip into output_dir; returns its path. SystemExit with the fix on failure."""
    missing = missing_wheels(root)
    if missing:
        raise SystemExit(f"missing wheels {missing}: run scripts/fetch_wheels.sh first")
    manifest = tomllib.loads((root / "blender_manifest.toml").read_text())
    output_dir.mkdir(parents=True, exist_ok=True)
    out = output_dir / f"{manifest['id']}-{manifest['version']}.zip"
    cmd = [sys.executable, str(blender_ext_script()), "build", "--source-dir", str(root), "--output-filepath",
           str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0 or not out.is_file():
        raise SystemExit(f"building the extension failed:\n{done.stdout}\n{done.stderr}")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output-dir", type=Path, default=ROOT / "dist")
    print(build(parser.parse_args().output_dir))


if __name__ == "__main__":
    main()
