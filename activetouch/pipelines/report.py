"""Evaluation report: results.json, report.md with the paper-style tables, and figures."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # headless: the daemon and CI have no display
import matplotlib.pyplot as plt
import numpy as np

from activetouch.pipelines.evaluation import public_runs
from activetouch.session.loop import display_label
from activetouch.storage import atomic_write_text

POLICY_STYLE = {
    "tree": ("tab:blue", "-"),
    "greedy": ("tab:orange", "--"),
    "random": ("tab:gray", ":"),
}


def _fmt(v: Any) -> str:
    if v is None:
        return "never"
    if isinstance(v, float):
        return f"{v:g}"
    return str(v)


def saved_text(paired: dict[str, Any]) -> str:
    """Mean moves saved with its interval, e.g. "+0.60 [+0.31, +0.92]"."""
    m = paired["mean_moves_saved"]
    if m is None:
        return "n/a"
    ci = paired.get("ci95")
    return f"{m:+.2f}" + (f" [{ci[0]:+.2f}, {ci[1]:+.2f}]" if ci else "")


def distance_figure(
    runs: list[dict[str, Any]], objects: list[str], policies: list[str], max_moves: int, out: Path
) -> None:
    n = len(objects)
    cols = min(4, n)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(
        rows, cols, figsize=(3.6 * cols, 2.8 * rows), squeeze=False, sharey=True
    )
    x = np.arange(1, max_moves + 1)
    for ax, obj in zip(axes.flat, objects, strict=False):
        for pol in policies:
            curves = []
            for r in runs:
                if r["object"] != obj or r["policy"] != pol or not r["distance_to_true"]:
                    continue
                d = [v for v in r["distance_to_true"] if v is not None]
                if not d:
                    continue
                # After a run stops its histogram no longer changes: carry the last value.
                curves.append(np.pad(d, (0, max_moves - len(d)), mode="edge")[:max_moves])
            if not curves:
                continue
            c = np.array(curves)
            color, ls = POLICY_STYLE.get(pol, ("k", "-"))
            ax.plot(x, np.median(c, axis=0), color=color, ls=ls, label=pol)
            ax.fill_between(x, *np.percentile(c, [25, 75], axis=0), color=color, alpha=0.15)
        ax.set_title(obj)
        ax.set_xlabel("grasps")
        ax.grid(alpha=0.3)
    for ax in axes.flat[n:]:
        ax.axis("off")
    for row in axes:
        row[0].set_ylabel("distance to true class")
    axes.flat[0].legend(fontsize=8)
    fig.suptitle(
        "Inner-product distance to the true class's training histogram "
        "(median and quartiles over seeds)",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def _hist_scatter(ax, h: np.ndarray, bins: int, title: str) -> None:
    h = np.asarray(h, dtype=float)
    if h.sum() > 0:
        h = h / h.max()
    idx = np.nonzero(h)[0]
    i0, rem = np.divmod(idx, bins * bins)
    i1, i2 = np.divmod(rem, bins)
    ax.scatter(
        i0, i1, i2, s=4 + 80 * h[idx], c=h[idx], cmap="viridis", vmin=0, vmax=1, depthshade=False
    )
    ax.set_xlim(0, bins - 1)
    ax.set_ylim(0, bins - 1)
    ax.set_zlim(0, bins - 1)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_zticks([])
    ax.set_title(title, fontsize=8)


def histogram_figure(
    runs: list[dict[str, Any]],
    objects: list[str],
    policies: list[str],
    class_hist: dict[str, np.ndarray],
    bins: int,
    out: Path,
) -> None:
    cols = 1 + len(policies)
    fig = plt.figure(figsize=(2.2 * cols, 2.1 * len(objects)))
    for i, obj in enumerate(objects):
        ax = fig.add_subplot(len(objects), cols, i * cols + 1, projection="3d")
        _hist_scatter(ax, class_hist.get(obj, np.zeros(bins**3)), bins, f"{obj}: training")
        for j, pol in enumerate(policies):
            r = next((r for r in runs if r["object"] == obj and r["policy"] == pol), None)
            ax = fig.add_subplot(len(objects), cols, i * cols + 2 + j, projection="3d")
            if r is not None:
                _hist_scatter(
                    ax,
                    np.array(r["_counts"]),
                    bins,
                    f"{pol} (seed {r['seed']}): {display_label(r['final_label'])}",
                )
    fig.suptitle("Triangle histograms (l0, l1, a0 bins): training vs recognised", fontsize=10)
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)


def contacts_figure(
    runs: list[dict[str, Any]], objects: list[str], policies: list[str], out: Path
) -> None:
    fig = plt.figure(figsize=(2.3 * len(objects), 2.3 * len(policies)))
    for i, pol in enumerate(policies):
        for j, obj in enumerate(objects):
            ax = fig.add_subplot(
                len(policies), len(objects), i * len(objects) + j + 1, projection="3d"
            )
            r = next((r for r in runs if r["object"] == obj and r["policy"] == pol), None)
            if r is not None and r["_contacts"]:
                pts = np.concatenate([np.asarray(c).reshape(-1, 3) for c in r["_contacts"]])
                if len(pts):
                    ax.scatter(*pts.T, s=6, c=pts[:, 2], cmap="plasma", depthshade=False)
                    lim = np.abs(pts).max() * 1.1
                    ax.set_xlim(-lim, lim)
                    ax.set_ylim(-lim, lim)
                    ax.set_zlim(-lim, lim)
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_zticks([])
            ax.set_title(f"{obj} / {pol}", fontsize=8)
    fig.suptitle(
        "Contacts felt during recognition (object frame, seed of the first run)", fontsize=10
    )
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)


def write_report(
    out_dir: Path,
    runs: list[dict[str, Any]],
    summary: dict[str, Any],
    command: str,
    class_hist: dict[str, np.ndarray],
    bins: int,
    extra_md: str = "",
) -> Path:
    out_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(
        out_dir / "results.json",
        json.dumps({"command": command, "runs": public_runs(runs), "summary": summary}, indent=1)
        + "\n",
    )
    objects, policies, budget = summary["objects"], summary["policies"], summary["max_moves"]
    distance_figure(runs, objects, policies, budget, out_dir / "distance_vs_moves.png")
    histogram_figure(runs, objects, policies, class_hist, bins, out_dir / "histograms.png")
    contacts_figure(runs, objects, policies, out_dir / "contacts.png")

    seeds = sorted({r["seed"] for r in runs})
    protocol = (
        "runs end when confident"
        if summary.get("stop_when_confident")
        else "every run uses the whole budget (the paper's protocol)"
    )
    lines = [
        "# Active tactile recognition in the twin",
        "",
        f"Produced by `{command}`",
        "",
        f"{len(objects)} objects x {len(policies)} policies x {len(seeds)} seeds, "
        f"move budget {budget} grasps (the first, random grasp included), "
        f"{protocol}. "
        "Moves are grasps until the label is correct; 'never' = not within the budget.",
        "",
    ]
    if summary.get("robot_errors"):
        errs = ", ".join(f"sim.{k} = {v:g}" for k, v in summary["robot_errors"].items())
        lines.extend(
            [
                f"With the real robot's errors (docs/benchmark.md): {errs}; each run's "
                "placement error and faulty sensors are in results.json (`errors`).",
                "",
            ]
        )

    def table(title: str, key: str) -> None:
        lines.extend(
            [
                f"## {title}",
                "",
                "| object | " + " | ".join(policies) + " |",
                "|---|" + "---|" * len(policies),
            ]
        )
        for o in objects:
            cells = [_fmt(summary["table"][o][p][key]) for p in policies]
            lines.append(f"| {o} | " + " | ".join(cells) + " |")
        lines.append("")

    table("Median moves until first correct", "median_first_correct")
    table("Median moves until 3-in-a-row correct", "median_stable_correct")
    lines.extend(
        [
            "## Runs correct at the end (of " + str(len(seeds)) + " seeds)",
            "",
            "| object | " + " | ".join(policies) + " |",
            "|---|" + "---|" * len(policies),
        ]
    )
    for o in objects:
        cells = [f"{summary['table'][o][p]['final_correct']}" for p in policies]
        lines.append(f"| {o} | " + " | ".join(cells) + " |")
    lines.extend(
        [
            "",
            "## Per policy",
            "",
            "| policy | objects correct at the end (majority of seeds) | runs correct at "
            "the end | median moves to first correct | mean moves to first correct "
            "(never = budget + 1) | mean robot s to first correct (never = the run's) | "
            "mean robot s per run | mean planning s per run |",
            "|---|---|---|---|---|---|---|---|",
        ]
    )
    for p in policies:
        s = summary["per_policy"][p]
        lines.append(
            f"| {p} | {s['objects_final_correct_majority']} of {len(objects)} | "
            f"{s['final_correct_rate']:.0%} | {_fmt(s['median_first_correct'])} | "
            f"{s['mean_first_correct_capped']:.2f} | "
            f"{s.get('mean_robot_s_to_first_correct', float('nan')):.1f} | "
            f"{s.get('mean_robot_s', float('nan')):.1f} | {s['mean_planning_s']:.3f} |"
        )
    if summary["paired_by_seed"]:
        lines.extend(
            [
                "",
                "## Tree against the baselines, paired by object and seed",
                "",
                "| comparison | mean moves saved by tree (95 % CI) | tree fewer | ties | "
                "tree more | sign test p | mean robot s saved by tree (95 % CI) | "
                "tree faster / slower | sign test p |",
                "|---|---|---|---|---|---|---|---|---|",
            ]
        )
        for k, v in summary["paired_by_seed"].items():
            rs = v.get("robot_s_saved")
            timed = (
                f"{rs['mean']:+.1f} [{rs['ci95'][0]:+.1f}, {rs['ci95'][1]:+.1f}] | "
                f"{rs['tree_faster']} / {rs['tree_slower']} | {rs['sign_p']:.3f}"
                if rs and rs["mean"] is not None
                else "| |"
            )
            lines.append(
                f"| {k} | {saved_text(v)} | {v['tree_fewer']} | {v['ties']} | "
                f"{v['tree_more']} | {v.get('sign_p', float('nan')):.3f} | {timed} |"
            )
    lines.extend(
        [
            "",
            "## Figures",
            "",
            "![distance to the true class against moves](distance_vs_moves.png)",
            "",
            "![training histograms beside recognised ones](histograms.png)",
            "",
            "![contact clouds per policy](contacts.png)",
            "",
        ]
    )
    if extra_md:
        lines.extend([extra_md, ""])
    atomic_write_text(out_dir / "report.md", "\n".join(lines))
    return out_dir / "report.md"
