"""The registry lists the built-in methods in name order whatever was imported first: a script (or a test file)
that imports a method's module before the registry's discovery no longer moves that method to the front of the
scene-file reference, the parameter table and every listing (docs/scene-files.md read stale after
tests/test_weiler2018.py had been collected)."""
from __future__ import annotations

import json
import subprocess
import sys

CODE = """
import json, sys
for module in sys.argv[1:]:
    __import__(module)
from warp_sph.methods import registry
print(json.dumps([list(registry.solvers()), list(registry.boundaries()), list(registry.forces())]))
"""


def listing(*modules: str) -> list:
    out = subprocess.run([sys.executable, "-c", CODE, *modules], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_method_imported_first_keeps_its_place():
    plain = listing()
    assert plain[2] == sorted(plain[2]) and plain[0] == sorted(plain[0])
    assert listing("warp_sph.methods.forces.weiler2018", "warp_sph.methods.solvers.wcsph",
                   "warp_sph.methods.boundaries.penalty") == plain
