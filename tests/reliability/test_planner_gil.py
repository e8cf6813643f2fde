"""A long tree search does not hold the interpreter: the daemon's e-stop, status and signal
threads keep running while the runner thread plans (finding 2 of the reliability issue)."""

from __future__ import annotations

import threading
import time

import numpy as np

from activetouch.planning.bench import _root, make_problem
from activetouch.planning.mcts import SearchResult, TreeSearch
from activetouch.planning.mcts_kernels import run_simulations

HANG_S = 30.0  # a hang bound: every wait below ends as soon as what it waits for happens


def test_the_compiled_search_loop_is_built_without_the_interpreter_lock() -> None:
    assert run_simulations.targetoptions.get("nogil") is True


def test_other_threads_run_while_a_search_runs() -> None:
    """The main thread runs Python while the compiled loop is part way through a search (it
    reads the loop's simulation count, neither 0 nor the whole budget) and its interrupt()
    ends that search early. Were the lock held, the main thread would only run again once
    the search had finished, and would never see it part way."""
    pr = make_problem(60, 7, seed=0)
    ts = TreeSearch(pr.model, pr.kernel)
    visited, counts, cells = _root(pr, 0)
    ts.search(0, visited, counts, cells, horizon=5, simulations=50, rng=np.random.default_rng(0))
    # Seconds of work on any machine: a search interrupted in its first moments is the norm.
    sims = 200_000
    # The search's tree, allocated now so the loop runs on it: its root's visit count is the
    # number of simulations the running loop has begun.
    tree = ts._tree_for(sims)

    def plan(out: dict[str, object]) -> None:
        try:
            out["result"] = ts.search(
                0,
                visited,
                counts,
                cells,
                horizon=20,
                simulations=sims,
                rng=np.random.default_rng(1),
            )
        except BaseException as e:  # re-raised by the main thread
            out["error"] = e

    deadline = time.monotonic() + HANG_S
    while True:
        ts.clear_interrupt()
        tree.node_vis[0] = 0
        out: dict[str, object] = {}
        t = threading.Thread(target=plan, args=(out,), daemon=True)
        t.start()
        seen = 0  # simulations begun, as read part way through the search
        while t.is_alive() and not seen:
            begun = int(tree.node_vis[0])
            if 0 < begun < sims:
                seen = begun
                ts.interrupt()
            else:
                time.sleep(0.001)
        t.join(HANG_S)
        assert not t.is_alive(), f"an interrupted search still ran after {HANG_S} s"
        error = out.get("error")
        if isinstance(error, BaseException):
            raise error
        result = out["result"]
        assert isinstance(result, SearchResult)
        if seen and result.simulations < sims:
            break
        # The search ended before this thread ran (or before the interrupt landed): again,
        # until HANG_S. With the lock held, every attempt ends here.
        assert time.monotonic() < deadline, (
            f"the main thread never ran while a search was part way in {HANG_S} s"
        )
    assert seen <= result.simulations < sims
    assert len(result.poses) > 0  # an interrupted search still answers with its best path
