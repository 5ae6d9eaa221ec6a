"""scripts/build_extension.py without the 300 MB: the full build's wheel list (``--with-torch
--dry-run``) from a fake source folder with empty wheel files, the error naming the missing
torch wheel and the fix, and one full build through Blender's builder from fake wheels (the
zip's name and manifest; the source manifest keeps the light list)."""
from __future__ import annotations

import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "scripts" / "build_extension.py"
sys.path.insert(0, str(ROOT / "scripts"))
import build_extension  # noqa: E402

TORCH = "./wheels/torch-2.13.0+cpu-cp311-cp311-manylinux_2_28_x86_64.whl"
# what Blender 5.0 ships in its own Python (bpy 5.0.1's requirements and bundled modules)
BLENDER_SHIPS = {"numpy", "requests", "certifi", "idna", "charset_normalizer", "urllib3", "zstandard", "cython",
                 "materialx", "openimageio", "pyopencolorio", "pxr", "openvdb", "oslquery"}


def light() -> list[str]:
    return tomllib.loads((ROOT / "blender_manifest.toml").read_text())["wheels"]


def fake_source(tmp_path: Path, skip: str | None = None) -> Path:
    """The repository's manifest and torch list with an empty file for every wheel but skip."""
    root = tmp_path / "src"
    (root / "scripts").mkdir(parents=True)
    (root / "wheels").mkdir()
    shutil.copy(ROOT / "blender_manifest.toml", root)
    shutil.copy(ROOT / "scripts" / "torch_wheels.txt", root / "scripts")
    (root / "__init__.py").write_text("def register():\n    pass\n\n\ndef unregister():\n    pass\n")
    for w in build_extension.wheel_list(root, with_torch=True):
        if w != skip:
            (root / w).touch()
    return root


def dry_run(root: Path, *flags: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), "--dry-run", "--source-dir", str(root),
                           "--output-dir", str(root / "dist"), *flags], capture_output=True, text=True)


def test_full_dry_run_lists_light_then_torch_wheels(tmp_path):
    root = fake_source(tmp_path)
    done = dry_run(root, "--with-torch")
    assert done.returncode == 0, done.stderr
    out, *wheels = done.stdout.splitlines()
    assert Path(out) == root / "dist" / "rvr_laaf-0.1.0-full.zip"
    assert wheels[:len(light())] == light() and wheels[len(light())] == TORCH
    names = {Path(w).name.split("-")[0].lower() for w in wheels}
    assert {"torch", "filelock", "typing_extensions", "setuptools", "sympy", "mpmath", "networkx", "jinja2",
            "markupsafe", "fsspec"} <= names and len(names) == len(wheels)
    assert not names & BLENDER_SHIPS  # never re-bundle what Blender's Python has


def test_default_dry_run_keeps_the_light_list(tmp_path):
    done = dry_run(fake_source(tmp_path))
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines()[1:] == light() and done.stdout.splitlines()[0].endswith("rvr_laaf-0.1.0.zip")


def test_missing_torch_wheel_names_the_file_and_the_fix(tmp_path):
    done = dry_run(fake_source(tmp_path, skip=TORCH), "--with-torch")
    assert done.returncode == 1
    assert Path(TORCH).name in done.stderr and "scripts/fetch_wheels.sh --with-torch" in done.stderr
    assert dry_run(fake_source(tmp_path / "b", skip=TORCH)).returncode == 0  # the light build does not need it


def test_full_build_from_fake_wheels(tmp_path):
    pytest.importorskip("bpy")
    root = fake_source(tmp_path)
    before = (root / "blender_manifest.toml").read_text()
    out = build_extension.build(tmp_path / "dist", root, with_torch=True)
    assert out == tmp_path / "dist" / "rvr_laaf-0.1.0-full.zip"
    with zipfile.ZipFile(out) as z:
        manifest = tomllib.loads(z.read("blender_manifest.toml").decode())
        names = set(z.namelist())
    full = light() + build_extension.torch_wheels(root)
    assert manifest["wheels"] == full and {w[2:] for w in full} <= names and "__init__.py" in names
    assert (root / "blender_manifest.toml").read_text() == before
    assert [p.name for p in (tmp_path / "dist").iterdir()] == [out.name]  # the staged copy is gone


def test_default_build_packs_only_the_listed_wheels(tmp_path):
    pytest.importorskip("bpy")
    root = fake_source(tmp_path)  # ./wheels also holds the torch wheels, as after fetch_wheels.sh --with-torch
    with zipfile.ZipFile(build_extension.build(tmp_path / "dist", root)) as z:
        assert sorted(n for n in z.namelist() if n.startswith("wheels/")) == sorted(w[2:] for w in light())
