"""PyBullet twin: the ReFlex and BarrettHand hands with tactile sites, the floating wrist and
the Baxter arm, the table and the object, the real robot's errors as options. Implements the
same Hand / Arm interfaces as the real drivers.

Importing this package does not load PyBullet (a config naming the twin device types must not
cost that); the modules that use it call `import_pybullet_quietly()` first."""

import os
import sys

# How the twin arm gets to a goal (`arm.path`): at once, or along a straight joint-space line.
PATHS = ("teleport", "straight")


def import_pybullet_quietly() -> None:
    """PyBullet's C code prints its build date to stderr on every import (once per worker
    process too), which buries the CLI's own messages; import it with fd 2 on /dev/null."""
    if "pybullet" in sys.modules:
        return
    sys.stderr.flush()
    saved = os.dup(2)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        # deferred: PyBullet (50 ms) only for the twin, and imported here with fd 2 silenced
        import pybullet  # noqa: F401
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)
