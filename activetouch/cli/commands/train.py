"""`activetouch train`: collect the missing training grasps in the twin, then fit the model."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from activetouch import paths
from activetouch.cli.main import add_common_options
from activetouch.config import Config, load_config, profile_line
from activetouch.errors import ConfigError
from activetouch.objects.library import PAPER_SIM_OBJECTS, ObjectLibrary
from activetouch.pipelines.executors import add_executor_options, check_executor
from activetouch.planning.observation_builder import pose_spread
from activetouch.recognition.dataset import Dataset
from activetouch.sim.contact_probe import ContactShare, advice, dataset_shares


def register(sub: argparse._SubParsersAction) -> None:

    p = sub.add_parser("train", help="collect training grasps in the twin and fit the model")
    p.add_argument(
        "--objects",
        default=",".join(PAPER_SIM_OBJECTS),
        help="comma-separated object names (default: the paper's 7 simulated objects)",
    )
    p.add_argument("--out", metavar="DIR", default=None, help="model directory to write")
    p.add_argument("--dataset", metavar="DIR", default=None, help="dataset directory")
    p.add_argument("--workers", type=int, default=None, help="parallel collection processes")
    add_executor_options(p, "the collections (one per object)")
    add_common_options(p)
    p.set_defaults(func=run)


def parse_objects(text: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise ConfigError("--objects: give at least one object name")
    if len(set(names)) != len(names):
        raise ConfigError(f"--objects: a name is repeated in {text!r}")
    return names


def train(
    root: Path,
    names: list[str],
    cfg_path: str | None,
    overrides: list[str],
    out: Path | None,
    dataset: Path | None,
    workers: int | None,
    console: Console,
    executor: str = "local",
    address: str | None = None,
) -> Path:
    # deferred: loads numba
    from activetouch.pipelines.training import collect, dataset_variant, fit_and_save

    cfg = load_config(cfg_path, overrides)
    if workers is not None and workers < 1:
        raise ConfigError(f"--workers must be >= 1, got {workers}")
    check_executor(executor, address)
    library = ObjectLibrary(paths.objects_dir(root))
    with console.status("preparing the object library"):
        library.ensure_builtins()
    dataset = dataset or paths.default_dataset(root, dataset_variant(cfg))
    out = out or paths.default_model(root, cfg.hand.family)
    console.print(f"profile {profile_line(cfg)}", highlight=False)

    t0 = time.perf_counter()
    with Progress(
        TextColumn("{task.description:>14}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=console,
        transient=False,
    ) as bar:
        tasks: dict[str, int] = {}

        def on_progress(name: str, done: int, total: int) -> None:
            if name not in tasks:
                tasks[name] = bar.add_task(name, total=total)
            bar.update(tasks[name], completed=done)

        stats = collect(
            library, dataset, names, cfg, workers, on_progress, executor=executor, address=address
        )
    t_collect = time.perf_counter() - t0
    with console.status("fitting the classifier and the observation model"):
        t1 = time.perf_counter()
        model = fit_and_save(dataset, names, cfg, out)
        t_fit = time.perf_counter() - t1

    shares = {s.name: s for s in contact_shares(dataset, names, cfg)}
    table = Table(title="training")
    for col in ("object", "new grasps", "unreachable", "already stored", "< 3 contacts"):
        table.add_column(col, justify="right" if col != "object" else "left")
    for s in sorted(stats, key=lambda s: names.index(s.name)):
        sh = shares[s.name]
        few = f"{sh.share:.0%} of {sh.grasps}"
        table.add_row(
            s.name,
            str(s.grasped),
            str(s.skipped),
            str(s.already_done),
            f"[yellow]{few}[/]" if sh.high else few,
        )
    console.print(table)
    for s in stats:
        if s.reachable is not None:  # the arm said which grid poses it reaches (collect.py)
            console.print(
                f"{s.name}: the arm reaches {s.reachable} of the {s.checked} grid poses checked",
                highlight=False,
            )
    for s in stats:
        if s.failed:  # moves to poses the wrist had accepted that then failed
            why, n = max(s.failed.items(), key=lambda kv: kv[1])
            console.print(
                f"{s.name}: {sum(s.failed.values())} moves failed (most: {n} x {why})",
                highlight=False,
            )
    for line in advice(list(shares.values()), cfg):
        console.print(f"[yellow]warning:[/] {line}", highlight=False, soft_wrap=True)
    arm = any(s.reachable is not None for s in stats)
    if any(s.skipped for s in stats):
        console.print(
            f"unreachable: poses the {cfg.arm.type} arm cannot reach collision-free for this "
            "placement, or where the open hand would meet the table or the object; they are "
            "skipped, as on the robot"
            if arm
            else "unreachable: poses where the open hand (fingers flat: the ReFlex ~0.38 m "
            "across, the BH8 ~0.29 m) would meet the table; they are skipped, as on the robot",
            highlight=False,
        )
    obs = model.observation
    grid_poses = sum(s.grasped + s.skipped + s.already_done for s in stats)
    grasped = sum(s.grasped for s in stats)
    if arm:
        console.print(
            f"the {cfg.arm.type} arm grasped at {grasped} of {grid_poses} grid poses "
            f"({grasped / max(grid_poses, 1):.0%}; the paper's real robot: 138 actions of 1063)",
            highlight=False,
        )
    console.print(
        f"collected in {t_collect:.1f} s, fitted in {t_fit:.1f} s: {len(names)} classes, "
        f"{obs.n_poses} poses, {obs.n_actions} actions, granularity {obs.granularity}"
    )
    if model.likelihood is not None:
        cell = float(model.config["observation"]["translation_cell_m"])  # as the model pooled
        console.print(pooling_line(model.likelihood.poses, cfg, cell), highlight=False)
    console.print(f"model written to {out}")
    return out


# Above this a pooled pose may send the hand to another size's grid pose (measured on the hard
# library: 6 cm cells, up to 5.8 cm apart, left a bottle's lip out of reach; docs/benchmark.md).
SPREAD_ADVICE_M = 0.02


def pooling_line(poses: np.ndarray, cfg: Config, cell_m: float | None = None) -> str:
    """How far from its training poses the model's pooled poses send the hand (`cell_m`: the
    translation cell the model pooled by, default the setting)."""

    oc = cfg.observation
    cell = oc.translation_cell_m if cell_m is None else cell_m
    d = pose_spread(poses, cell, oc.quaternion_cell)
    if not len(d):
        return "no training poses"
    how = " chosen for the library's sizes" if oc.cells_from == "library" else ""
    line = (
        f"pooled poses ({cell * 100:g} cm cells{how}): a grasp is made up to "
        f"{d.max() * 100:.1f} cm from a pose a class was trained at (90 % within "
        f"{np.percentile(d, 90) * 100:.1f} cm)"
    )
    if d.max() > SPREAD_ADVICE_M:
        line += (
            "; if the objects differ much in size, finer cells (observation.translation_cell_m"
            "=0.01) let the planner choose each size's own poses (docs/benchmark.md)"
        )
    return line


def contact_shares(dataset: Path, names: list[str], cfg: Config) -> list[ContactShare]:
    """Per object, the share of its training grasps (at its current grid) with fewer than 3
    contacts."""
    # deferred: loads numba
    from activetouch.pipelines.training import grid_pose_ids

    ds = Dataset.open(dataset)
    return dataset_shares(ds, names, grid_pose_ids(ds, names, cfg))


def run(args: argparse.Namespace) -> int:
    root = paths.data_dir(args.data)
    train(
        root,
        parse_objects(args.objects),
        args.config,
        args.overrides,
        Path(args.out) if args.out else None,
        Path(args.dataset) if args.dataset else None,
        args.workers,
        Console(),
        args.executor,
        args.address,
    )
    return 0
