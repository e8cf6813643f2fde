"""A long evaluation cut short resumes: each finished run is journaled as it finishes, and
the same evaluation again makes only the runs the journal does not hold."""

from __future__ import annotations

import json
import types
from pathlib import Path

import pytest

from activetouch.cli.main import main
from activetouch.config import load_config
from activetouch.errors import ConfigError
from activetouch.pipelines import evaluation
from activetouch.pipelines.evaluation import Job, job_key, run_all
from activetouch.pipelines.journal import RunJournal


def test_journal_reads_back_whole_lines_only(tmp_path):
    path = tmp_path / "runs.jsonl"
    j = RunJournal(path)
    j.add("a", {"seed": 0, "labels": ["cup"]})
    j.add("b", {"seed": 1, "final_probability": float("nan")})
    with open(path, "a") as f:
        f.write('["not", "a run"]\n{"key": "c", "record": {"seed": 2')  # cut by the crash
    again = RunJournal(path)
    assert len(again) == 2
    assert again.get("a") == {"seed": 0, "labels": ["cup"]}
    assert again.get("c") is None
    again.remove()
    assert not path.exists() and len(RunJournal(path)) == 0


def test_journal_in_place_of_a_directory_is_said(tmp_path):
    (tmp_path / "runs.jsonl").mkdir()
    with pytest.raises(ConfigError, match="not a file"):
        RunJournal(tmp_path / "runs.jsonl")


def _stub_runs(monkeypatch, fail_on: int | None = None) -> list[int]:
    """run_job records each job it is asked for and fails at `fail_on`; keys are the jobs."""
    asked: list[int] = []

    def run_job(job: int) -> dict:
        asked.append(job)
        if job == fail_on:
            raise RuntimeError("the power went")
        return {"job": job, "square": job * job}

    monkeypatch.setattr(evaluation, "run_job", run_job)
    monkeypatch.setattr(evaluation, "job_key", lambda job: f"job-{job}")
    return asked


def test_run_all_resumes_from_its_journal(tmp_path, monkeypatch):
    jobs = [4, 1, 3, 2]
    asked = _stub_runs(monkeypatch, fail_on=3)
    with pytest.raises(RuntimeError):
        run_all(jobs, workers=1, journal=RunJournal(tmp_path / "j"))  # type: ignore[arg-type]
    assert asked == [4, 1, 3]
    assert len(RunJournal(tmp_path / "j")) == 2  # the two that finished

    asked = _stub_runs(monkeypatch)
    seen: list[tuple[int, int]] = []
    out = run_all(
        jobs,  # type: ignore[arg-type]
        workers=1,
        progress=lambda i, n: seen.append((i, n)),
        journal=RunJournal(tmp_path / "j"),
    )
    assert asked == [3, 2]  # only the runs the journal lacked
    assert out == [{"job": j, "square": j * j} for j in jobs]  # in the jobs' order
    assert seen == [(2, 4), (3, 4), (4, 4)]


def _job(tmp_path: Path, **kw) -> Job:
    model = tmp_path / "model"
    model.mkdir(exist_ok=True)
    if not (model / "model.json").exists():
        (model / "model.json").write_text("{}")
    base = dict(
        model_dir=str(model),
        library_root=str(tmp_path / "objects"),
        object_name="cup",
        policy="greedy",
        seed=0,
        max_moves=5,
        cfg=load_config(None, []),
    )
    return Job(**{**base, **kw})  # type: ignore[arg-type]


def test_job_key_follows_what_a_run_depends_on(tmp_path, monkeypatch):
    mesh = tmp_path / "cup.obj"
    mesh.write_text("v 0 0 0\n")
    library = types.SimpleNamespace(get=lambda name: types.SimpleNamespace(visual_mesh=mesh))
    monkeypatch.setattr(evaluation, "ObjectLibrary", lambda root: library)
    key = job_key(_job(tmp_path))
    assert key == job_key(_job(tmp_path))
    assert key != job_key(_job(tmp_path, seed=1))
    assert key != job_key(_job(tmp_path, policy="tree"))
    assert key != job_key(_job(tmp_path, cfg=load_config(None, ["sim.fault_dead=4"])))
    (tmp_path / "model" / "model.json").write_text('{"retrained": true}')
    retrained = job_key(_job(tmp_path))
    assert retrained != key
    mesh.write_text("v 0 0 0\nv 1 0 0\n")
    assert job_key(_job(tmp_path)) != retrained


@pytest.mark.slow  # about 8 s (three recognitions, figures)
def test_eval_cut_short_resumes(trained_home, tmp_path, monkeypatch, capsys):
    out = tmp_path / "r"
    args = ["eval", "--data", str(trained_home), "--out", str(out), "--workers", "1"]
    args += ["--seeds", "0-1", "--max-moves", "2", "--policies", "greedy", "--objects", "cup"]
    args += ["--set", "grid.step_deg=40"]
    real = evaluation.run_job
    made: list[int] = []

    def cut_at_second(job):
        made.append(job.seed)
        if len(made) == 2:
            raise KeyboardInterrupt  # Ctrl-C during the second run
        return real(job)

    monkeypatch.setattr(evaluation, "run_job", cut_at_second)
    assert main(args) == 130  # "interrupted"
    assert not (out / "results.json").exists()
    kept = [json.loads(line) for line in (out / "runs.jsonl").read_text().splitlines()]
    assert [k["record"]["seed"] for k in kept] == [0]

    made.clear()
    monkeypatch.setattr(evaluation, "run_job", lambda job: made.append(job.seed) or real(job))
    assert main(args) == 0
    assert made == [1]  # seed 0 was not made again
    assert "resuming: 1 runs" in capsys.readouterr().out
    runs = json.loads((out / "results.json").read_text())["runs"]
    assert [r["seed"] for r in runs] == [0, 1]
    assert runs[0]["labels"] == kept[0]["record"]["labels"]
    assert not (out / "runs.jsonl").exists()  # every run is in results.json
