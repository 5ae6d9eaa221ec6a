"""Fixtures for tests that import bpy: the repository root imported as the package ``rvr_laaf``
(as Blender would import the extension), registered for one test and unregistered after."""
from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[2]
PACKAGE = "rvr_laaf"


@pytest.fixture(scope="session")
def addon_package(tmp_path_factory):
    """The repository root imported as ``rvr_laaf`` via a symlink on a temporary sys.path entry."""
    pytest.importorskip("bpy")
    root = tmp_path_factory.mktemp("addon_path")
    (root / PACKAGE).symlink_to(REPO_ROOT, target_is_directory=True)
    sys.path.insert(0, str(root))
    try:
        yield importlib.import_module(PACKAGE)
    finally:
        sys.path.remove(str(root))


@pytest.fixture
def factory_scene():
    """A fresh factory-settings file with an empty scene; returns that scene."""
    bpy = pytest.importorskip("bpy")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy.context.scene


@pytest.fixture
def registered(addon_package, factory_scene):
    """The add-on registered in a fresh file (unregistered afterwards)."""
    addon_package.register()
    try:
        yield addon_package
    finally:
        addon_package.unregister()
