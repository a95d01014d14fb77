"""The documentation cannot drift from the code: the site builds in strict mode, the generated
scene-file reference is current, every page is in the nav and one click from the README, and every
example in README.md and docs/ runs (docs/about.md, "How the docs are kept true", says how each kind
of block is run)."""
from __future__ import annotations

import contextlib
import io
import os
import re
import shlex
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import pytest

from test_blender import BLENDER_PYTHON  # the Python with bpy that the Blender tests use

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
README = ROOT / "README.md"
BIN = Path(sys.executable).parent
EXAMPLE_FRAMES = 3  # warp-sph run / sweep in the examples run this many frames

FENCE = re.compile(r"^(?P<indent>[ \t]*)```(?P<lang>[^\n`]*)\n(?P<body>.*?)^(?P=indent)```[ \t]*$", re.S | re.M)


def pages() -> list[Path]:
    """README.md, then every page of docs/, then the repository pages the site includes."""
    return [README] + sorted(DOCS.glob("*.md")) + [ROOT / "benchmarks" / "README.md", ROOT / "CHANGELOG.md"]


def blocks(path: Path) -> list[tuple[str, str]]:
    """(language, code) of every fenced block, in order, dedented."""
    return [(m["lang"].strip().split(" ")[0], textwrap.dedent(m["body"])) for m in FENCE.finditer(path.read_text())]


def _env() -> dict:
    env = dict(os.environ)
    env.pop("WARP_SPH_VERBOSE", None)
    env["PATH"] = f"{BIN}{os.pathsep}{env.get('PATH', '')}"
    env["NO_MKDOCS_2_WARNING"] = "1"
    return env


# --- the site ---------------------------------------------------------------------------------------

def test_site_builds_in_strict_mode(tmp_path):
    """mkdocs build --strict: broken links and anchors, pages missing from the nav, a stale generated
    table, a public name without a docstring or a scene without its picture fail it."""
    site = tmp_path / "site"
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)], cwd=ROOT,
                       capture_output=True, text=True, timeout=300, env=_env())
    assert r.returncode == 0, (r.stdout + r.stderr)[-4000:]
    api = (site / "api.html").read_text()
    assert "advance_frame" in api and "into a run folder" in api  # generated from the docstrings
    assert (site / "benchmarks" / "results" / "dam_break_surface_000013.png").is_file()  # repository files copied in
    reference = (site / "scene-files.html").read_text()
    assert "dfsph.target_density_error" in reference


def test_build_checks_can_fail(tmp_path, monkeypatch):
    """The checks the build runs report a stale reference and a public function without a docstring."""
    import warp_sph
    from warp_sph import docs

    page = tmp_path / docs.REFERENCE_PAGE
    page.write_text((DOCS / docs.REFERENCE_PAGE).read_text().replace("| `particle_radius` | float | m | 0.025 |",
                                                                     "| `particle_radius` | float | m | 0.02 |"))
    assert docs.stale_pages(tmp_path) == [str(page)]
    assert docs.main(["--check", str(tmp_path)]) == 1
    assert docs.main([str(tmp_path)]) == 0 and docs.stale_pages(tmp_path) == []

    def undocumented():
        pass

    monkeypatch.setattr(warp_sph, "undocumented", undocumented, raising=False)
    monkeypatch.setattr(warp_sph, "__all__", warp_sph.__all__ + ["undocumented"])
    assert docs.missing_docstrings() == ["undocumented"]


def test_scene_reference_is_current_and_complete():
    from warp_sph import docs
    from warp_sph.scene import all_parameters

    assert docs.main(["--check", str(DOCS)]) == 0
    text = (DOCS / docs.REFERENCE_PAGE).read_text()
    for p in all_parameters():
        assert f"| `{p.path}` |" in text or f"### {p.path}\n" in text, p.path
    assert "| `pbf.max_iterations` | int | - | 50 | >= 1 and <= 10000 | `pbf` solver |" in text


def test_every_page_in_the_nav_and_one_click_from_the_readme():
    import yaml

    class Loader(yaml.SafeLoader):
        pass

    Loader.add_multi_constructor("tag:yaml.org,2002:python/", lambda loader, suffix, node: None)
    config = yaml.load((ROOT / "mkdocs.yml").read_text(), Loader=Loader)

    def entries(nav):
        for item in nav:
            for value in (item.values() if isinstance(item, dict) else [item]):
                yield from (entries(value) if isinstance(value, list) else [value])

    nav = set(entries(config["nav"]))
    readme_links = set(re.findall(r"\]\((docs/[^)#]+)", README.read_text()))
    for page in sorted(DOCS.glob("*.md")):
        assert page.name in nav, f"docs/{page.name} is not in the nav of mkdocs.yml"
        assert f"docs/{page.name}" in readme_links, f"README.md does not link docs/{page.name}"


def test_readme_is_a_front_page():
    text = README.read_text()
    assert len(text.splitlines()) <= 160
    assert not re.search(r"#\d+|\bissue\b", text, re.I)  # no issue numbers or history on the front page
    for target in re.findall(r"\]\(([^)#]+)", text):
        if not target.startswith(("http://", "https://")):
            assert (ROOT / target).exists(), target
    assert "../shared" not in text


def test_quick_start_has_two_commands_and_ci_runs_the_test_one():
    text = README.read_text()
    block = text.split("## Quick start", 1)[1].split("```sh", 1)[1].split("```", 1)[0]
    commands = [line.split("#")[0].strip() for line in block.strip().splitlines()]
    assert commands == ["make run", "make test"]
    assert "make test" in (ROOT / ".ci" / "run").read_text()
    assert "docs" in re.search(r"pip install[^\n]*-e '\.\[([^\]]*)\]'", (ROOT / "Makefile").read_text()).group(1)


def test_docs_say_how_to_reach_the_commands():
    """After ``make run`` the documented ``warp-sph ...`` commands live in .venv: the README and the
    getting-started page say to activate it (or to call .venv/bin/warp-sph); pip installs are from
    the checkout (warp-sph is not on PyPI)."""
    for path in (README, DOCS / "getting-started.md"):
        text = path.read_text()
        assert "source .venv/bin/activate" in text and ".venv/bin/warp-sph" in text, path
    for path in pages():
        assert "pip install 'warp-sph[" not in path.read_text(), path
    for path in (README, DOCS / "getting-started.md"):
        text = path.read_text()
        for m in re.finditer(r"pip install[^\n`]*", text):
            assert m.group(0).startswith("pip install -e") and ".venv/bin/pip install" in text, (path, m.group(0))


# --- the examples -----------------------------------------------------------------------------------

def _in_process(args: list[str], cwd: Path) -> tuple[int, str]:
    """warp-sph ARGS in this process (no start-up and kernel loading per command): (status, output)."""
    from warp_sph.cli import main

    out, here = io.StringIO(), os.getcwd()
    os.chdir(cwd)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
            try:
                rc = main(args)
            except SystemExit as e:  # --help
                rc = e.code or 0
    finally:
        os.chdir(here)
    return rc, out.getvalue()


def _help_check(argv: list[str], env: dict, cwd: Path) -> None:
    """Run the command's --help and check that every option the example uses is in it."""
    words = [w for w in argv[1:] if not w.startswith("-")]
    sub = words[:2] if argv[0] == "warp-sph" and words[:1] == ["bench"] else words[:1]
    if argv[0] == "warp-sph":
        rc, text = _in_process([*sub, "--help"], cwd)
    else:
        r = subprocess.run([str(BIN / argv[0]) if (BIN / argv[0]).exists() else argv[0], *sub, "--help"], cwd=cwd,
                           capture_output=True, text=True, timeout=120, env=env)
        rc, text = r.returncode, r.stdout + r.stderr
    assert rc == 0, text
    for option in (w.split("=")[0] for w in argv if w.startswith("--")):
        assert option in text, f"{' '.join(argv)}: {option} is not an option of {' '.join([argv[0], *sub])}"


def _adjusted(argv: list[str]) -> list[str]:
    """warp-sph run / sweep for EXAMPLE_FRAMES frames; preview frames clamped to them."""
    out, k = [], 0
    while k < len(argv):
        w = argv[k]
        if w == "--frames" and argv[1] in ("run", "sweep"):
            k += 2
            continue
        if w == "--frame" and argv[1] == "preview":
            out += [w, str(min(int(argv[k + 1]), EXAMPLE_FRAMES))]
            k += 2
            continue
        out.append(w)
        k += 1
    if argv[1] in ("run", "sweep") and "--resume" not in argv:
        out += ["--frames", str(EXAMPLE_FRAMES)]
    return out


def run_command(line: str, cwd: Path, env: dict, page: Path) -> None:
    argv = shlex.split(line, comments=True)
    if not argv:
        return
    env = dict(env)
    if argv[0] == "flock":  # flock LOCKFILE command ...
        argv = argv[2:]
    while "=" in argv[0] and not argv[0].startswith("-"):
        key, _, value = argv.pop(0).partition("=")
        env[key] = value
    argv[0] = {".venv/bin/warp-sph": "warp-sph", ".venv/bin/pip": "pip", "python3": "python"}.get(argv[0], argv[0])
    where = f"{page.relative_to(ROOT)}: {line.strip()}"
    if argv[0] == "make":
        r = subprocess.run(["make", "-n", *argv[1:]], cwd=ROOT, capture_output=True, text=True, timeout=60)
        assert r.returncode == 0, f"{where}\n{r.stderr}"
        if argv[1:2] == ["run"]:  # what the recipe runs, in the scratch folder
            run_command("warp-sph run", cwd, env, page)
        return
    if argv[0] == "source":
        assert (ROOT / argv[1]).exists(), where
        return
    if argv[0] == "pip":
        extras = re.fullmatch(r"\.\[([\w,]+)\]", argv[-1])
        assert argv[1:3] == ["install", "-e"] and extras, f"{where}: only pip install -e '.[EXTRA]' is checked"
        declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
        for extra in extras.group(1).split(","):
            assert extra in declared, f"{where}: no extra {extra!r} in pyproject.toml"
        return
    if argv[0] == "dask" or (argv[0] == "warp-sph" and (argv[1] == "bench" or "--scheduler" in argv)):
        _help_check(argv, env, cwd)
        return
    if argv[0] == "warp-sph":
        rc, text = _in_process(_adjusted(argv)[1:] + (["--no-progress"] if argv[1] in ("run", "sweep") else []), cwd)
        assert rc == 0, f"{where}\n{text[-3000:]}"
        return
    if argv[0] == "python":
        argv = [sys.executable, *argv[1:]]
    else:
        pytest.fail(f"{where}: no rule to run {argv[0]!r} in tests/test_docs.py")
    r = subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=600, env=env)
    assert r.returncode == 0, f"{where}\n{(r.stdout + r.stderr)[-3000:]}"


def _check_toml(code: str, cwd: Path, where: str) -> None:
    from warp_sph.scene import load_scene, scene_from_dict
    from warp_sph.sweep.cases import load_sweep_file

    data = tomllib.loads(code)
    name = re.match(r"#\s*(\S+\.toml)\s*\n", code)
    if name:
        path = cwd / name.group(1)
        path.write_text(code)
        load_sweep_file(str(path)) if "sweep" in data else load_scene(str(path))
    elif "sweep" not in data and "case" not in data:  # a fragment: valid when added to the default scene
        with open(ROOT / "scenes" / "dam_break.toml", "rb") as f:
            scene = tomllib.load(f)
        scene.update(data)
        scene_from_dict(scene, source=where, base_dir=cwd)


def _is_blender(code: str) -> bool:
    return bool(re.search(r"^import bpy", code, re.M))


@pytest.mark.parametrize("page", pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_examples_run(page, tmp_path):
    """Every sh, toml and python block of the page, in a scratch folder of its own."""
    env = _env()
    python = []
    for lang, code in blocks(page):
        where = f"{page.relative_to(ROOT)}: {code.splitlines()[0] if code.strip() else ''}"
        if lang in ("sh", "bash", "shell"):
            for line in re.sub(r"\\\n\s*", " ", code).splitlines():
                run_command(line, tmp_path, env, page)
        elif lang == "toml":
            _check_toml(code, tmp_path, where)
        elif lang == "python" and not _is_blender(code):
            python.append(code)
    if python:
        script = tmp_path / "example.py"  # Warp reads kernel source from a real file
        script.write_text("\n\n".join(python))
        r = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=600,
                           env=env)
        assert r.returncode == 0, f"{page.relative_to(ROOT)}\n{r.stdout[-2000:]}\n{r.stderr[-3000:]}"
        # quiet: the examples print their own lines only (no Warp banner, module-load lines or warnings)
        assert r.stderr == "", r.stderr
        assert not re.search(r"^Warp |Module .* load on device|CUDA", r.stdout, re.M), r.stdout


def test_example_runner_can_fail(tmp_path):
    """A command with an option that does not exist, a make target that does not exist, an extra that
    is not declared and a command without a rule fail the example test."""
    for line in ("warp-sph bench scaling --no-such-option", "warp-sph scenes --no-such-option", "make no-such-target",
                 ".venv/bin/pip install -e '.[no_such_extra]'", "rm -rf runs"):
        with pytest.raises((AssertionError, pytest.fail.Exception)):
            run_command(line, tmp_path, _env(), README)


def test_scripting_example_adds_its_stage():
    """The scripting page's stage runs where it says: its printed graph and timing rows."""
    code = "\n".join(c for lang, c in blocks(DOCS / "scripting.md") if lang == "python")
    assert "['neighbors', 'density', 'stabilize', 'divergence', 'swirl', 'source', 'pressure', 'integrate']" in code
    import warp_sph as ws

    sim = ws.Simulation(ws.load_scene("dam_break", ["particle_radius=0.05", "output.usd=false"]))
    names = sim.graph.names()
    names.insert(names.index("source"), "swirl")
    assert str(names) in code  # the list the example prints is the default solver's graph plus the stage


@pytest.mark.skipif(BLENDER_PYTHON is None, reason="no Python with bpy (Blender as a Python module): `make test` "
                    "installs bpy 5.0.1 into .venv/blender, or set WARP_SPH_BLENDER_PYTHON (see tests/test_blender.py)")
@pytest.mark.slow
def test_blender_render_example(tmp_path):
    """The Blender page's render script imports a run and renders a frame with its materials."""
    code = next(c for lang, c in blocks(DOCS / "blender.md") if lang == "python" and _is_blender(c))
    script = tmp_path / "render_water.py"
    script.write_text(code.replace("scene.cycles.samples = 16", "scene.cycles.samples = 1").replace(
        "resolution_x, scene.render.resolution_y = 800, 450", "resolution_x, scene.render.resolution_y = 160, 90"))
    r = subprocess.run([str(BIN / "warp-sph"), "run", "drop_into_pool", "--frames", "3", "--out", "run",
                        "--set", "particle_radius=0.05", "--no-progress"], cwd=tmp_path, capture_output=True,
                       text=True, timeout=600, env=_env())
    assert r.returncode == 0, r.stderr
    python = BLENDER_PYTHON
    r = subprocess.run([python, str(script), "--", str(tmp_path / "run" / "drop_into_pool.usdc"), "3"],
                       cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, (r.stdout + r.stderr)[-3000:]
    assert (tmp_path / "run" / "water_000003.png").stat().st_size > 1000


def test_timing_table_keeps_the_first_call_apart():
    """The first call of a stage loads (or compiles) its kernels: timing_table reports it apart and
    ms_per_call is the mean of the other calls (the scripting page prints both)."""
    import time

    import warp_sph as ws

    sim = ws.Simulation(ws.load_scene("dam_break", ["particle_radius=0.1", "output.usd=false"]))
    calls = []

    def slow_first(sim, dt):
        time.sleep(0.25 if not calls else 0.0)
        calls.append(dt)

    sim.graph.insert(ws.Stage("slow_first", slow_first), before="integrate")
    sim.advance_frame()
    row = {r["stage"]: r for r in sim.graph.timing_table()}["slow_first"]
    assert row["calls"] == len(calls) > 2
    assert row["first_call_seconds"] >= 0.25
    assert row["ms_per_call"] < 25.0  # 0.25 s averaged over a frame's few dozen steps would be more
    assert row["ms_per_call"] == pytest.approx(1e3 * (row["seconds"] - row["first_call_seconds"]) / (row["calls"] - 1))
