"""The project's own exception types: messages a user can act on, no traceback needed."""


class WarpSphError(Exception):
    """Base class of every error warp-sph raises on purpose."""


class SceneError(WarpSphError):
    """A scene file or scene value is invalid (names the file, the key path and what was expected)."""


class StepGraphError(WarpSphError):
    """The step graph is inconsistent: a field read before it is written, two writers, ..."""


class SimulationError(WarpSphError):
    """The simulation left its valid range (non-finite values, particles escaping, ...)."""


class OutputError(WarpSphError):
    """An output folder or file cannot be written without losing something the user has."""


class PlanError(WarpSphError):
    """A plan cannot be made (budget too small, target error out of reach, a scene that cannot be
    calibrated, a malformed --budget): one line, CLI exit status 2."""
