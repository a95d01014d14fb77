"""A plain (non-editable) ``pip install .`` into a fresh virtual environment works: the device
code is importable as ``warp_sph.kernels``, built-in scenes are found by name, tests pass against
the installed package (run from outside the tree) and ``python -m pytest`` still works from the
checkout, whose source folder comes first on sys.path there."""
import os
import shutil
import subprocess
import venv
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_non_editable_install_in_fresh_venv(tmp_path):
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True).create(env_dir)
    py = env_dir / "bin" / "python"
    src = tmp_path / "src"
    # copy the tracked sources only (no .venv, no build leftovers)
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(".venv", ".git", "runs", "build", "*.egg-info",
                                                             "__pycache__", ".pytest_cache", "results"))
    env = dict(os.environ, PIP_DISABLE_PIP_VERSION_CHECK="1")
    r = subprocess.run([str(py), "-m", "pip", "install", "--quiet", f"{src}[test]"], env=env,
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    code = (
        "import warp_sph, warp_sph.kernels.smoothing as k, warp_sph.kernels.density, warp_sph.rigid;"
        "from warp_sph.scene import load_scene, list_scenes;"
        "s = load_scene('dam_break'); o = load_scene('obstacle');"
        "import os; assert 'site-packages' in warp_sph.__file__, warp_sph.__file__;"
        "assert os.path.isfile(o.obstacles[0].file), o.obstacles[0].file;"
        # the data folders (packages of their own in pyproject.toml): the validation scenes and experiments' data
        "from warp_sph.validation.errors import DATA_DIR; import warp_sph.scenes as sc;"
        "assert len(list(DATA_DIR.glob('*.csv'))) >= 7, DATA_DIR;"
        "assert os.path.isfile(os.path.join(os.path.dirname(sc.__file__), 'validation', 'lobovsky.toml'));"
        "print(sorted(n for n, _ in list_scenes()), k.SMOOTHING_FUNCTIONS.keys())"
    )
    r = subprocess.run([str(py), "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "dam_break" in r.stdout and "obstacle" in r.stdout
    # the console script is installed and answers
    r = subprocess.run([str(env_dir / "bin" / "warp-sph"), "scenes"], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and "hydrostatic" in r.stdout, r.stderr[-2000:]
    # tests against the installed package: a copy of some test files, run from outside the tree
    outside = tmp_path / "outside"
    (outside / "tests").mkdir(parents=True)
    quick = ["conftest.py", "sph_oracle.py", "test_scene.py", "test_smoothing.py", "test_check_usd.py"]
    for name in quick:
        shutil.copy(ROOT / "tests" / name, outside / "tests" / name)
    (outside / "tests" / "test_where.py").write_text(
        "import warp_sph, warp_sph.kernels\n"
        "def test_installed():\n"
        "    assert 'site-packages' in warp_sph.__file__ and 'site-packages' in warp_sph.kernels.__file__\n")
    r = subprocess.run([str(py), "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests"], cwd=outside, env=env,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    # ... and from the checkout itself (the source folder shadows the installed package there)
    r = subprocess.run([str(py), "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests/test_scene.py"], cwd=src,
                       env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
