
import pytest
import warp as wp

wp.config.quiet = True
if hasattr(wp.config, "log_level"):
    wp.config.log_level = getattr(wp, "LOG_WARNING", 30)


def _devices():
    devs = ["cpu"]
    try:
        if wp.get_cuda_device_count() > 0:
            devs.append("cuda:0")
    except Exception:
        pass
    return devs


DEVICES = _devices()


@pytest.fixture(params=DEVICES)
def device(request):
    return request.param
