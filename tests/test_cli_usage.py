"""The command line as a new user meets it: ``warp-sph`` alone, and wrong input found on a tour of a fresh
clone (each: one line naming the key or value and what was expected, exit status 2, nothing written)."""
from warp_sph.cli import build_parser, main as cli_main


def test_no_command_prints_short_usage_and_the_commands_exit_2(capsys):
    """``warp-sph`` with no command: a usage line, every command with its one-line help, and one error line
    pointing at --help, on stderr (a usage error), exit status 2; not the full help."""
    assert cli_main([]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    lines = err.strip().splitlines()
    assert lines[0].startswith("usage: warp-sph")
    assert lines[-1] == "warp-sph: error: no command given; see warp-sph --help, or warp-sph COMMAND --help"
    sub = next(a for a in build_parser()._actions if a.__class__.__name__ == "_SubParsersAction")
    names = list(sub.choices)
    assert {"run", "check", "bench", "plan", "plot"} <= set(names)
    listed = [line.split()[0] for line in lines[2:-1]]
    assert listed == names  # each command once, in the parser's order, with its help text
    assert all(len(line.split(None, 1)) == 2 for line in lines[2:-1])
    full = build_parser().format_help()
    assert len(err) < len(full) and "--verbose" not in err.replace("[--verbose]", "")
    assert cli_main(["--verbose"]) == 2  # only the global flag: the same usage error


def test_bench_without_a_benchmark_prints_short_usage_exit_2(capsys):
    """``warp-sph bench`` alone: the same short usage (its benchmarks listed), stderr, exit status 2."""
    assert cli_main(["bench"]) == 2
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert out == "" and lines[0] == "usage: warp-sph bench COMMAND [ARGS]"
    assert lines[-1] == ("warp-sph: error: bench: no command given; see warp-sph bench --help, or "
                         "warp-sph bench COMMAND --help")
    assert {"whitewater", "validation", "report"} <= {line.split()[0] for line in lines[2:-1]}


def test_interrupt_line_says_where_resume_restarts(tmp_path):
    """After a Ctrl-C the run's frames stay, but --resume restarts from the latest checkpoint and removes the
    files of the frames after it (computed again): the interrupt line says so, so that nothing surprises."""
    from warp_sph.run.runner import _resume_hint

    assert _resume_hint(tmp_path, 5) is None  # no checkpoint yet: nothing to resume from
    (tmp_path / "checkpoints").mkdir()
    for k in (1, 11):
        (tmp_path / "checkpoints" / f"checkpoint_{k:06d}.npz").write_bytes(b"")
    assert _resume_hint(tmp_path, 14) == (f"warp-sph run --resume {tmp_path} continues from its checkpoint of "
                                          "frame 11 (frames 12..14 are computed again)")
    assert _resume_hint(tmp_path, 11).endswith("checkpoint of frame 11")


def test_a_folder_given_as_the_scene_says_so(tmp_path, capsys):
    """``warp-sph run runs/dam_break`` (a run folder where a scene goes, meaning --resume) said 'scene file not
    found' of a folder that exists: now it says it is a folder, and for a run folder how to continue it."""
    run = tmp_path / "runs" / "dam_break"
    run.mkdir(parents=True)
    (run / "run.json").write_text("{}")
    for folder, tail in ((tmp_path, ""), (run, f" (it holds a run: warp-sph run --resume {run} continues it)")):
        assert cli_main(["check", str(folder)]) == 2
        err = capsys.readouterr().err.strip()
        assert err == (f"warp-sph: error: {folder}: is a folder; expected a scene file (.toml) or a built-in scene "
                       f"name{tail}")
    assert sorted(p.name for p in run.iterdir()) == ["run.json"]


def test_a_folder_named_without_a_slash_says_so_and_a_builtin_name_still_wins(tmp_path, monkeypatch, capsys):
    """``warp-sph run ok1`` (a run folder in the working directory, written without a slash) said 'no such scene
    file or built-in scene'; a folder named like a built-in scene (``--out dam_break``) does not shadow it."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "ok1").mkdir()
    (tmp_path / "ok1" / "run.json").write_text("{}")
    assert cli_main(["check", "ok1"]) == 2
    assert capsys.readouterr().err.strip() == ("warp-sph: error: ok1: is a folder; expected a scene file (.toml) or a "
                                               "built-in scene name (it holds a run: warp-sph run --resume ok1 "
                                               "continues it)")
    (tmp_path / "dam_break").mkdir()
    from warp_sph.scene import load_scene

    assert load_scene("dam_break").name == "dam_break"


def test_version(capsys):
    """``warp-sph --version`` was 'unrecognized arguments': now the package's version, exit status 0."""
    import pytest

    import warp_sph

    with pytest.raises(SystemExit) as e:
        cli_main(["--version"])
    assert e.value.code == 0 and capsys.readouterr().out.strip() == f"warp-sph {warp_sph.__version__}"
