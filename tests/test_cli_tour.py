"""What a new user's tour of a fresh clone tripped over: a scene named beside --resume was ignored when it
was the default's name, errors about a --set value blamed the scene file, options without help text."""
import argparse

import pytest

from warp_sph.cli import build_parser, main
from warp_sph.scene.load import with_override


def _one_error_line(capsys) -> str:
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("warp-sph: error: ") and "Traceback" not in err, err
    return lines[0]


@pytest.mark.parametrize("scene", ["dam_break", "hydrostatic"])
def test_a_scene_named_with_resume_is_refused(scene, tmp_path, capsys, monkeypatch):
    """``warp-sph run dam_break --resume DIR`` silently resumed DIR's own scene (the check compared the name
    with the default, dam_break); any scene named beside --resume is refused before the run is read."""
    monkeypatch.chdir(tmp_path)
    folder = tmp_path / "r"
    folder.mkdir()
    (folder / "notes.txt").write_text("mine")
    assert main(["run", scene, "--resume", str(folder)]) == 2
    line = _one_error_line(capsys)
    assert line.endswith(f"continues the run in {folder} with its own scene and folder; drop the scene {scene!r}")
    assert [p.name for p in folder.iterdir()] == ["notes.txt"] and not (tmp_path / "runs").exists()


@pytest.mark.parametrize("command", ["run", "check"])
@pytest.mark.parametrize("override, key", [("particle_radius=-1", "particle_radius"),
                                           ("time.dt_min=1", "time.dt_min"),
                                           ("fluid[0].max=[9,9,9]", "fluid[0].max")])
def test_an_error_about_a_set_value_names_the_override(command, override, key, tmp_path, capsys, monkeypatch):
    """``--set particle_radius=-1`` said "dam_break.toml: particle_radius: ..., got -1", and the user looked
    for -1 in the file. Now the line ends with where the value came from; exit 2, nothing written."""
    monkeypatch.chdir(tmp_path)
    assert main([command, "dam_break", "--set", override]) == 2
    line = _one_error_line(capsys)
    assert "dam_break.toml: " in line and line.endswith(f" (from --set {key})"), line
    assert not (tmp_path / "runs").exists()


def test_with_override_matches_the_key_or_its_table_only():
    msg = "/s/dam_break.toml: fluid[0]: box [0, 0, 0]..[9, 9, 9] is not inside the container"
    assert with_override(msg, ["fluid[0].max=[9,9,9]"]).endswith("(from --set fluid[0].max)")
    assert with_override(msg, ["fluid[1].max=[9,9,9]", "particle_radius=0.1"]) == msg
    assert with_override(msg, {"fluid": [{}]}).endswith("(from --set fluid)")
    assert with_override("/s/a.toml: scene file not found", ["particle_radius=1"]) == "/s/a.toml: scene file not found"
    # an error about the file itself is not blamed on an override of a key that shares its name's start
    assert with_override("/s/a.toml: time.dt: expected x", ["time.dt_min=1"]) == "/s/a.toml: time.dt: expected x"


def _parsers(parser: argparse.ArgumentParser, name: str):
    yield name, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub, p in action.choices.items():
                yield from _parsers(p, f"{name} {sub}")


def test_every_option_has_help_text():
    """``warp-sph check --help`` listed --set with no text (export --format, bench scaling --scene/--solver
    and bench splishsplash --particle-radius too): every option of every command and benchmark says what it does."""
    from warp_sph.benchmarks.runner import build_parser as bench_parser

    missing = [f"{name} {action.option_strings or action.dest}"
               for root, prefix in ((build_parser(), "warp-sph"), (bench_parser(), "warp-sph bench"))
               for name, p in _parsers(root, prefix) for action in p._actions
               if not isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)) and not action.help
               and action.nargs != argparse.REMAINDER]  # warp-sph bench ARGS...: handed to the bench parser
    assert missing == []
