import os

import pytest
import warp as wp

wp.config.quiet = True
if hasattr(wp.config, "log_level"):
    wp.config.log_level = getattr(wp, "LOG_WARNING", 30)


def _cuda_count() -> int:
    try:
        from warp_sph.core.device import init_warp

        init_warp()  # Warp's start-up without its "no CUDA driver" line (warp_sph.core.device)
        return wp.get_cuda_device_count()
    except Exception:
        return 0


#: the CUDA half of every test that takes the ``device`` fixture is collected everywhere and skipped (before
#: the fixture runs, so nothing is compiled) where warp sees no CUDA device
HAS_CUDA = _cuda_count() > 0
DEVICES = ["cpu", pytest.param("cuda:0", marks=pytest.mark.skipif(
    not HAS_CUDA, reason="no CUDA device (warp sees none): the CUDA half of this test did not run"))]


@pytest.fixture(params=DEVICES)
def device(request):
    """The warp device of a physics test: "cpu", and "cuda:0" where one exists (skipped, saying so, where not)."""
    return request.param


@pytest.fixture(autouse=True, scope="session")
def _session_plan_cache(tmp_path_factory):
    """warp-sph plan's calibration cache (and the Pareto plot it draws beside it) of any test, or of a command a
    test runs, goes to a folder of this session, never to the user's ~/.cache/warp-sph/plan (which would also
    make a test's calibration depend on an earlier run's)."""
    before = os.environ.get("WARP_SPH_CACHE_DIR")
    os.environ["WARP_SPH_CACHE_DIR"] = str(tmp_path_factory.mktemp("plan_cache"))
    yield
    if before is None:
        os.environ.pop("WARP_SPH_CACHE_DIR", None)
    else:
        os.environ["WARP_SPH_CACHE_DIR"] = before
