"""`activetouch bench planner`: the figures it prints and writes."""

from __future__ import annotations

import json
from pathlib import Path

from activetouch.planning import bench


def test_bench_planner_writes_speed_and_memory(tmp_path: Path) -> None:
    out = tmp_path / "planner.json"
    argv = ["--poses", "60", "--classes", "5", "--sims", "60", "--repeats", "2"]
    assert bench.main([*argv, "--json", str(out)]) == 0
    got = json.loads(out.read_text())
    assert [r["horizon"] for r in got["results"]] == list(bench.HORIZONS)
    for r in got["results"]:
        assert r["sims_per_s"] > 0 and r["actions"] == 59 and r["classes"] == 5
        assert abs(sum(r["observation_sources"].values()) - 1.0) < 0.01
    model = got["model"]
    assert model["poses"] == 60 and model["classes"] == 5
    assert 0 < model["search_index_bytes"] < model["array_bytes"]
    assert got["peak_rss_bytes"] >= got["peak_rss_bytes_after_build"] > model["array_bytes"]
