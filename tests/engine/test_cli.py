"""The ``rvr`` command line itself: fast help (no heavy imports while the parser is built) and
sub-command errors that show that sub-command's usage with a "did you mean" hint."""
from __future__ import annotations

import subprocess
import sys

import pytest

from rvr_addon import cli

HEAVY = {"torch", "cv2", "bpy", "dask", "mediapipe", "scipy", "onnxruntime", "distributed"}


def modules_after_build_parser(tops: set[str]) -> str:
    """Modules of the top-level packages ``tops`` that importing the CLI and building its parser loads
    (in a fresh interpreter), as the printed sorted list."""
    code = ("import rvr_addon.cli, sys; rvr_addon.cli.build_parser(); "
            f"print(sorted(m for m in sys.modules if m.split('.')[0] in {sorted(tops)!r}))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def test_building_the_parser_imports_no_heavy_module():
    loaded = modules_after_build_parser(HEAVY)
    assert loaded == "[]", f"rvr --help would import {loaded}"


def test_building_the_parser_imports_no_numpy_either():
    """Parsers take their choices and defaults from light modules (laaf.presets, depth.methods,
    temporal.settings, afnet.config, estimate.loss_weights, the batch and refocus packages)."""
    loaded = modules_after_build_parser({"numpy"})
    assert loaded == "[]", f"rvr --help would import {loaded}"


def test_every_subcommand_help_works(capsys):
    parser = cli.build_parser()
    commands = next(a for a in parser._actions if isinstance(a, cli.argparse._SubParsersAction)).choices
    assert {"render", "estimate", "stabilize", "autofocus", "batch", "train", "train-afnet"} <= set(commands)
    for name in commands:
        with pytest.raises(SystemExit) as ex:
            parser.parse_args([name, "--help"])
        assert ex.value.code == 0
        assert f"usage: rvr {name}" in capsys.readouterr().out


def test_light_names_match_the_engine():
    """The names the parsers offer without importing the engine are the engine's own."""
    from rvr_addon.depth import system
    from rvr_addon.depth.methods import METHODS
    from rvr_addon.laaf import combine, evaluate, presets, puller
    from rvr_addon.temporal import filter as temporal_filter
    from rvr_addon.temporal import flow
    from rvr_addon.temporal.settings import FLOW_PRESETS, TemporalSettings

    assert tuple(flow.PRESETS) == FLOW_PRESETS
    assert temporal_filter.TemporalSettings is TemporalSettings
    assert system.METHODS is METHODS
    assert combine.PRESETS is presets.PRESETS and combine.DEFAULT_PRESET == presets.DEFAULT_PRESET
    assert puller.PROFILES is presets.PROFILES and evaluate.EVAL_PRESETS is presets.EVAL_PRESETS


def test_typo_in_a_subcommand_flag_shows_that_subcommands_usage_and_a_hint(capsys):
    with pytest.raises(SystemExit) as ex:
        cli.main(["render", "--aperturee", "2"])
    assert ex.value.code == 2
    err = capsys.readouterr().err
    assert "usage: rvr render" in err
    assert "usage: rvr [-h]" not in err
    assert "rvr render: error: unrecognized arguments: --aperturee" in err
    assert "did you mean --aperture?" in err


def test_typo_hints_name_each_flag_and_stay_quiet_when_nothing_is_close(capsys):
    with pytest.raises(SystemExit):
        cli.build_parser().parse_args(["stabilize", "CACHE", "--flow-presett=fast", "--forse", "--zzzzzzzz"])
    err = capsys.readouterr().err
    assert "usage: rvr stabilize" in err
    assert "--flow-preset (for --flow-presett)" in err and "--force (for --forse)" in err
    assert "--zzzzzzzz" in err and "(for --zzzzzzzz)" not in err
    with pytest.raises(SystemExit):
        cli.build_parser().parse_args(["estimate", "clip.mp4", "-o", "cache", "--qqqqqq"])
    err = capsys.readouterr().err
    assert "usage: rvr estimate" in err and "did you mean" not in err
