# Two commands on a fresh machine with Python 3.11:  make run  |  make test
PYTHON ?= python3
VENV   ?= .venv
STAMP  := $(VENV)/.installed
# test processes (pytest-xdist; each test file runs whole in one of them): 2 halves the suite's time on 2 cores
TEST_WORKERS ?= 2
# Real Blender for tests/test_blender.py: bpy 5.0.1 (a wheel for Python 3.11 only, ~370 MB) in its own
# environment, because it pins numpy < 2 and must not downgrade the simulator's; the tests start it in a
# subprocess (WARP_SPH_BLENDER_PYTHON). On another Python the Blender tests skip and say why.
BLENDER_VENV  := $(VENV)/blender
BLENDER_STAMP := $(BLENDER_VENV)/.installed

.PHONY: run test docs clean

# plots (matplotlib): warp-sph plot, the plan's Pareto plot and the benchmark plots work as the docs say, and the
# tests draw them (without it they only checked the one-line refusal). The Makefile is a prerequisite: a checkout
# made before an extra joined this list gets it with the next make.
$(STAMP): pyproject.toml Makefile
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/python -m pip install --quiet --upgrade pip
	$(VENV)/bin/python -m pip install --quiet -e '.[test,preview,docs,plots]'
	touch $(STAMP)

$(BLENDER_STAMP): | $(STAMP)
	@if $(PYTHON) -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then \
		$(PYTHON) -m venv $(BLENDER_VENV) && \
		$(BLENDER_VENV)/bin/python -m pip install --quiet bpy==5.0.1 && touch $(BLENDER_STAMP); \
	else \
		echo "note: bpy 5.0.1 needs Python 3.11 ($(PYTHON) is not): the Blender tests will skip"; \
	fi

run: $(STAMP)
	$(VENV)/bin/warp-sph run $(ARGS)

test: $(STAMP) $(BLENDER_STAMP)
	WARP_SPH_BLENDER_PYTHON=$(BLENDER_VENV)/bin/python $(VENV)/bin/python -m pytest -n $(TEST_WORKERS) --dist loadfile $(PYTEST_ARGS)

docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/python -m mkdocs build --strict --site-dir site

clean:
	rm -rf $(VENV) build site *.egg-info
