"""Where a sweep's independent pieces run: this machine's process pool (the default) or Ray.

`ray_map` is the Ray side, shared by `eval` (one task per recognition) and `train` (one task
per object): each call one Ray task, the results handed back as they finish, with their
index, so a caller keeps its own order. Ray is optional (`pip install 'activetouch[ray]'`).
"""

from __future__ import annotations

import argparse
import ipaddress
import logging
import os
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from activetouch.errors import ActiveTouchError, ConfigError

log = logging.getLogger(__name__)

PARENT_POLL_S = 0.2  # how often a local pool worker checks that its parent still runs

EXECUTORS = ("local", "ray")
# Ray's single-machine mode (its default on macOS and Windows): a local Ray's servers listen
# on 127.0.0.1 only. Read when `ray` is imported, and inherited by the processes Ray starts.
RAY_LOCAL_ONLY_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"


def add_executor_options(p: argparse.ArgumentParser, what: str) -> None:
    """`--executor` and `--address`, as `eval` and `train` take them."""
    p.add_argument(
        "--executor",
        choices=EXECUTORS,
        default="local",
        help=f"where {what} run: this machine's processes (default) or Ray (optional: "
        "pip install 'activetouch[ray]')",
    )
    p.add_argument(
        "--address",
        default=None,
        help="--executor ray: the cluster to join (auto on a cluster node, or "
        "ray://HEAD:10001; default: start a Ray on this machine, listening on 127.0.0.1, "
        "with --workers CPUs)",
    )


def check_executor(executor: str, address: str | None = None) -> None:
    """ConfigError for an unknown executor, an --address without Ray, or Ray not installed;
    nothing is started."""
    if executor not in EXECUTORS:
        raise ConfigError(f"--executor: {executor!r} is not one of {', '.join(EXECUTORS)}")
    if address is not None and executor != "ray":
        raise ConfigError("--address: only with --executor ray (the cluster to run on)")
    if executor == "ray":
        import_ray(address)


def import_ray(address: str | None = None) -> Any:
    if address is None:  # before the first `import ray`: it reads the setting then
        os.environ.setdefault(RAY_LOCAL_ONLY_ENV, "0")
    try:
        import ray  # optional: not a dependency of activetouch
    except ImportError:
        raise ConfigError(
            "--executor ray needs Ray, which is not installed: pip install 'activetouch[ray]' "
            "(or use the default --executor local)"
        ) from None
    return ray


def init_ray(address: str | None = None, workers: int | None = None) -> Any:
    """The `ray` module, connected: to the cluster at `address`, or to a Ray this process
    starts on this machine (`workers` CPUs, default all). A Ray already running in this
    process is used as it is."""
    ray = import_ray(address)
    if ray.is_initialized():
        return ray
    kwargs: dict[str, Any] = {"address": address, "log_to_driver": False}
    if address is None:
        kwargs.update(num_cpus=workers, include_dashboard=False)
    try:
        ray.init(**kwargs)
    except (ConnectionError, ValueError, RuntimeError, TimeoutError) as e:
        where = f"--address {address}: cannot join the Ray cluster" if address else "Ray"
        raise ConfigError(f"{where}: {e}") from None
    ip = ray.util.get_node_ip_address() if address is None else None
    if ip is not None and not ipaddress.ip_address(ip).is_loopback:
        log.warning(
            "the Ray started here listens on %s, not only on 127.0.0.1: Ray was imported "
            "before %s=0 could be set",
            ip,
            RAY_LOCAL_ONLY_ENV,
        )
    return ray


def ray_map(
    fn: Callable[..., Any],
    calls: Sequence[tuple[Any, ...]],
    address: str | None = None,
    workers: int | None = None,
) -> Iterator[tuple[int, Any]]:
    """`fn(*calls[i])` as one Ray task per call; yields `(i, result)` as each task finishes.

    `fn` must be a module-level function (workers import it by name). A task's
    ActiveTouchError is raised here as itself (one line in the CLI, as with the local pool);
    other errors come as Ray's RayTaskError, with the worker's traceback. If the caller stops
    early (an error, Ctrl-C), the tasks not finished are cancelled."""
    ray = init_ray(address, workers)
    task = ray.remote(fn)
    index = {task.remote(*args): i for i, args in enumerate(calls)}
    waiting = list(index)
    try:
        while waiting:
            ready, waiting = ray.wait(waiting, num_returns=1)
            for ref in ready:
                try:
                    result = ray.get(ref)
                except ray.exceptions.RayTaskError as e:
                    if isinstance(e.cause, ActiveTouchError):
                        raise e.cause from None
                    raise
                yield index[ref], result
    finally:
        for ref in waiting:  # empty when every task finished
            ray.cancel(ref)


def exit_with_parent(parent: int) -> None:
    """A local pool worker's initializer: exit as soon as `parent` (the process that made the
    pool) is gone, however it ended, so a killed sweep leaves no worker running on."""

    def watch() -> None:
        while True:
            if os.getppid() != parent:  # re-parented: the parent died
                os._exit(3)
            time.sleep(PARENT_POLL_S)

    threading.Thread(target=watch, name="activetouch-parent-watch", daemon=True).start()
