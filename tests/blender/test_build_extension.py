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


def fake_wheel(path: Path) -> Path:
    """A small wheel shaped like mediapipe's: modules with kept and dropped models, a dist-info."""
    import base64
    import hashlib

    files = {"mediapipe/__init__.py": b"x = 1\n",
             "mediapipe/modules/face_detection/face_detection_full_range_sparse.tflite": b"keep" * 100,
             "mediapipe/modules/face_detection/face_detection_full_range_cpu.binarypb": b"graph",
             "mediapipe/modules/pose_landmark/pose_landmark_full.tflite": b"drop" * 1000,
             "mediapipe/modules/hand_landmark/hand_landmark_full.tflite": b"drop" * 1000,
             "mediapipe-0.10.14.dist-info/METADATA": b"Name: mediapipe\nVersion: 0.10.14\n",
             "mediapipe-0.10.14.dist-info/WHEEL": b"Wheel-Version: 1.0\nRoot-Is-Purelib: false\n"}
    digest = lambda d: base64.urlsafe_b64encode(hashlib.sha256(d).digest()).rstrip(b"=").decode()  # noqa: E731
    record = "".join(f"{n},sha256={digest(d)},{len(d)}\n" for n, d in files.items())
    record += "mediapipe-0.10.14.dist-info/RECORD,,\n"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in files.items():
            z.writestr(name, data)
        z.writestr("mediapipe-0.10.14.dist-info/RECORD", record)
    return path


def test_slim_mediapipe_wheel(tmp_path):
    """scripts/slim_wheel.py drops the unused models, keeps everything else, writes a RECORD that
    matches what it holds, tags build 1, and gives the same bytes twice (the manifest's name)."""
    import base64
    import csv
    import hashlib
    import io

    import slim_wheel

    upstream = "mediapipe-0.10.14-cp311-cp311-manylinux_2_17_x86_64.manylinux2014_x86_64.whl"
    assert "./wheels/" + slim_wheel.slim_name(upstream) in light()
    src = fake_wheel(tmp_path / upstream)
    (tmp_path / "a").mkdir()
    out = slim_wheel.slim(src, tmp_path / "a")
    assert out.name == slim_wheel.slim_name(upstream)
    with zipfile.ZipFile(out) as z:
        names = set(z.namelist())
        assert "mediapipe/modules/face_detection/face_detection_full_range_sparse.tflite" in names
        assert "mediapipe/modules/face_detection/face_detection_full_range_cpu.binarypb" in names
        assert not any("pose_landmark_full" in n or "hand_landmark" in n for n in names)
        assert "Build: 1" in z.read("mediapipe-0.10.14.dist-info/WHEEL").decode()
        rows = list(csv.reader(io.StringIO(z.read("mediapipe-0.10.14.dist-info/RECORD").decode())))
        assert {r[0] for r in rows} == names
        for name, digest, size in rows:
            if digest:
                data = z.read(name)
                want = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
                assert digest == "sha256=" + want
                assert int(size) == len(data)
    (tmp_path / "b").mkdir()
    assert slim_wheel.slim(src, tmp_path / "b").read_bytes() == out.read_bytes()


def test_slim_onnxruntime_wheel(tmp_path):
    """The onnxruntime copy keeps the Python module and its inference library, drops the C API
    library, the tools and the console scripts (scripts/slim_wheel.py DROP_PREFIXES)."""
    import slim_wheel

    upstream = "onnxruntime-1.31.1-cp311-cp311-manylinux_2_28_x86_64.whl"
    assert "./wheels/" + slim_wheel.slim_name(upstream) in light()
    files = {"onnxruntime/__init__.py": b"x = 1\n",
             "onnxruntime/capi/onnxruntime_pybind11_state.cpython-311-x86_64-linux-gnu.so": b"keep" * 100,
             "onnxruntime/capi/libonnxruntime_providers_shared.so": b"keep",
             "onnxruntime/capi/libonnxruntime.so.1.31.1": b"drop" * 1000,
             "onnxruntime/transformers/onnx_model.py": b"drop", "onnxruntime/quantization/quantize.py": b"drop",
             "onnxruntime/tools/symbolic_shape_infer.py": b"drop", "onnxruntime/LICENSE": b"MIT",
             "onnxruntime-1.31.1.dist-info/entry_points.txt": b"[console_scripts]\n",
             "onnxruntime-1.31.1.dist-info/METADATA": b"Name: onnxruntime\nVersion: 1.31.1\n",
             "onnxruntime-1.31.1.dist-info/WHEEL": b"Wheel-Version: 1.0\nRoot-Is-Purelib: false\n",
             "onnxruntime-1.31.1.dist-info/RECORD": b""}
    with zipfile.ZipFile(tmp_path / upstream, "w") as z:
        for name, data in files.items():
            z.writestr(name, data)
    out = slim_wheel.slim(tmp_path / upstream, tmp_path)
    with zipfile.ZipFile(out) as z:
        names = set(z.namelist())
    assert {"onnxruntime/__init__.py", "onnxruntime/LICENSE", "onnxruntime/capi/libonnxruntime_providers_shared.so",
            "onnxruntime/capi/onnxruntime_pybind11_state.cpython-311-x86_64-linux-gnu.so"} <= names
    assert not any("libonnxruntime.so" in n or "/transformers/" in n or "/tools/" in n or "/quantization/" in n
                   or n.endswith("entry_points.txt") for n in names)
