"""StepGraph's edits: a stage inserted or removed is checked, and a refused edit leaves the graph as it was."""
import pytest

from warp_sph.core.errors import StepGraphError
from warp_sph.core.step_graph import Stage, StepGraph


def _noop(sim, dt):
    pass


def _graph():
    return StepGraph([Stage("density", _noop, reads=("particle_x",), writes=("particle_density",)),
                      Stage("pressure", _noop, reads=("particle_density",), writes=("particle_pressure",)),
                      Stage("integrate", _noop, reads=("particle_pressure",), updates=("particle_x", "particle_v"))],
                     {"particle_x", "particle_v"})


def test_insert_and_remove_change_the_order_and_remove_returns_the_stage():
    g = _graph()
    g.insert(Stage("probe", _noop, reads=("particle_density",)), after="density")
    g.insert(Stage("first", _noop, reads=("particle_v",)), before="density")
    g.insert(Stage("last", _noop, reads=("particle_x",)))
    assert g.names() == ["first", "density", "probe", "pressure", "integrate", "last"]
    removed = g.remove("probe")
    assert removed.name == "probe" and g.names() == ["first", "density", "pressure", "integrate", "last"]


def test_a_refused_edit_leaves_the_graph_unchanged():
    g = _graph()
    before = list(g.stages)
    with pytest.raises(StepGraphError, match="reads 'particle_pressure' before any stage writes it"):
        g.insert(Stage("early", _noop, reads=("particle_pressure",)), before="density")
    assert g.stages == before
    with pytest.raises(StepGraphError, match="reads 'particle_density' before any stage writes it"):
        g.remove("density")  # pressure reads what only density writes
    assert g.stages == before
    with pytest.raises(StepGraphError, match="no stage named 'nothing'"):
        g.remove("nothing")
    with pytest.raises(StepGraphError, match="two stages are named 'density'"):
        g.insert(Stage("density", _noop))
    assert g.stages == before
