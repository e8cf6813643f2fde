"""Errors a user can cause and fix. The CLI prints them as one line, never as a traceback."""


class ActiveTouchError(Exception):
    """Base for errors caused by input, configuration or files, not by a bug."""


class ConfigError(ActiveTouchError):
    """A configuration file or option is invalid."""


class DataError(ActiveTouchError):
    """A dataset, model or mesh file is missing, corrupt, truncated or of the wrong version."""


class UnreachableError(ActiveTouchError):
    """The arm cannot reach a requested wrist pose (joint limits, collision, IK failure)."""


class PlanningError(ActiveTouchError):
    """The planner cannot produce a plan, e.g. no unvisited pose remains."""
