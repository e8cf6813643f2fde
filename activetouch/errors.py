"""Errors a user can cause and fix. The CLI prints them as one line, never as a traceback."""


class ActiveTouchError(Exception):
    """Base for errors caused by input, configuration or files, not by a bug."""


class ConfigError(ActiveTouchError):
    """A configuration file or option is invalid."""


class DataError(ActiveTouchError):
    """A dataset, model or mesh file is missing, corrupt, truncated or of the wrong version."""


class UnreachableError(ActiveTouchError):
    """The arm cannot reach a requested wrist pose (joint limits, collision, IK failure)."""


class MotionBlockedError(UnreachableError):
    """A motion stopped part way at a contact; `executed_s` trajectory seconds were done (robot
    time spent, though the pose was not reached)."""

    def __init__(self, message: str, executed_s: float = 0.0) -> None:
        super().__init__(message)
        self.executed_s = float(executed_s)


class PlanningError(ActiveTouchError):
    """The planner cannot produce a plan, e.g. no unvisited pose remains."""


class PlanningInterruptedError(PlanningError):
    """A plan was interrupted (cancel, e-stop, shutdown, time budget) before it had a path."""


class MessageError(ActiveTouchError):
    """A message received over Zenoh is malformed: not JSON, wrong schema version, bad field."""

    def __init__(self, message: str, field: str | None = None) -> None:
        super().__init__(message)
        self.field = field  # dotted path of the offending field, when known


class TrackingError(ActiveTouchError):
    """The measured arm did not follow the commanded trajectory (a joint lagged or blocked)."""


class NodeUnavailableError(ActiveTouchError):
    """A remote node (hand, arm, daemon) did not answer in time or its liveliness token dropped."""


class DeviceFaultError(ActiveTouchError):
    """A device reading that cannot be true: the device stopped itself; the message names the
    part and what to check."""


class RemoteError(ActiveTouchError):
    """A remote node failed with an error that has no counterpart here (e.g. a driver bug)."""


class StoppedError(ActiveTouchError):
    """A device refused or cut short a command because it was stopped (stop / e-stop)."""
