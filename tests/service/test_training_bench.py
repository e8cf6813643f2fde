import json

from activetouch.cli.main import main


def test_train_bench_reports_consistent_figures(tmp_path):
    out = tmp_path / "b.json"
    rc = main(
        [
            "bench",
            "train",
            "--objects",
            "sphere,cup",
            "--workers",
            "1",
            "--set",
            "grid.step_deg=60",
            "--json",
            str(out),
        ]
    )
    assert rc == 0
    fig = json.loads(out.read_text())
    assert fig["objects"] == 2
    assert fig["grasped"] + fig["unreachable"] == fig["grid_poses"] > 0
    assert fig["total_s"] >= fig["collect_s"] + fig["fit_s"]
    assert fig["pooled_poses"] <= fig["grasped"]
