"""`activetouch view`: the message -> Rerun logic on a memory recording (entity paths and
values read back from the recording), the Zenoh feed against the in-process daemon on the fake
devices during a recognition, the command's one-line error without Rerun, and (slow, when the
system has Chromium) the served web viewer in headless Chromium during a recognition."""

from __future__ import annotations

import io
import json
import sys
import threading
import time
from collections import defaultdict
from contextlib import suppress
from pathlib import Path
from typing import Any

import numpy as np
import pytest

rr = pytest.importorskip("rerun")

from activetouch import paths  # noqa: E402
from activetouch.config import WorkcellConfig  # noqa: E402
from activetouch.daemon.client import client_settings, open_client  # noqa: E402
from activetouch.transport import messages as m  # noqa: E402
from activetouch.transport.zenoh_session import ZenohSession  # noqa: E402
from activetouch.view.live import ProgressFeed, RerunServer, free_port  # noqa: E402
from activetouch.view.scene import SceneLogger, entity_name, library_meshes  # noqa: E402
from tests.conftest import FAKE_ROBOT  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
WAIT_S = 180.0  # generous: the machine may be loaded


def _progress(move: int, sid: str = "s1", **kw: Any) -> m.Progress:
    p = 0.4 + 0.1 * move
    fields: dict[str, Any] = {
        "session_id": sid,
        "move": move,
        "pose": m.PoseMsg(xyz=(0.1 * move, -0.05, 0.12), quat=(0.0, 0.0, 0.0, 1.0)),
        "n_contacts": 2,
        "top3": [("cup", p), ("sphere", 1 - p)],
        "contacts": [(0.01 * move, 0.02, 0.03), (-0.02, 0.0, 0.04)],
        "belief": [("cup", p), ("sphere", 1 - p), ("bottle", 0.0)],
        "object_pose": m.PoseMsg(xyz=(0.0, 0.0, 0.05), quat=(0.0, 0.0, 0.0, 1.0)),
        "object": "cup",
        "extents": (0.08, 0.08, 0.1),
    }
    fields.update(kw)
    return m.Progress(**fields)


def _read_back(mem: Any, tmp_path: Path) -> dict[str, list[dict[str, Any]]]:
    """entity path -> its rows (the components and sequence timelines each row has; time
    stamps left out). A component is a batch: a transform's translation is `[[x, y, z]]`."""
    import pyarrow as pa
    from rerun.chunk import RrdReader

    f = tmp_path / "view.rrd"
    f.write_bytes(mem.drain_as_bytes())
    rows: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for chunk in RrdReader(f).stream():
        batch = chunk.to_record_batch()
        names = [
            f.name
            for f in batch.schema
            if f.name != "rerun.controls.RowId" and not pa.types.is_timestamp(f.type)
        ]
        cols = {n: batch.column(n).to_pylist() for n in names}
        for i in range(batch.num_rows):
            rows[chunk.entity_path].append({n: cols[n][i] for n in names if cols[n][i] is not None})
    for path in rows:
        rows[path].sort(key=lambda r: r.get("grasp") or 0)
    return rows


def _memory_scene(**kw: Any) -> tuple[Any, Any, SceneLogger]:
    rec = rr.RecordingStream("activetouch-test", recording_id="test")
    mem = rec.memory_recording()
    return rec, mem, SceneLogger(rec, WorkcellConfig(), **kw)


# --------------------------------------------------------------------------- messages -> Rerun


def test_a_progress_sequence_logs_the_scene_and_the_belief(tmp_path: Path) -> None:
    rec, mem, scene = _memory_scene()
    for move in (1, 2, 3):
        scene.on_progress(_progress(move))
    rec.flush()
    rows = _read_back(mem, tmp_path)
    assert scene.grasps == 3 and scene.sessions == ["s1"]
    for path in (
        "/world",
        "/world/table",
        "/world/object",
        "/world/object/shape",
        "/world/object/hand",
        "/world/object/hand/palm",
        "/world/object/hand/axes",
        "/world/object/contacts",
        "/world/object/contacts_all",
        "/world/object/wrist_goals",
        "/world/object/wrist_goals/path",
        "/belief/cup",
        "/belief/sphere",
        "/belief/bottle",
        "/belief_bars",
        "/status",
    ):
        assert path in rows, (path, sorted(rows))
    wc = WorkcellConfig()
    (table,) = rows["/world/table"]
    assert table["Boxes3D:centers"] == [pytest.approx(wc.table_center)]
    assert table["Boxes3D:half_sizes"] == [pytest.approx([s / 2 for s in wc.table_size])]
    # The object: its placement every grasp, its shape once (a box of its extents: no library).
    placed = [r for r in rows["/world/object"] if "Transform3D:translation" in r]
    assert [r["grasp"] for r in placed] == [1, 2, 3]
    assert placed[-1]["Transform3D:translation"][0] == pytest.approx([0.0, 0.0, 0.05])
    (shape,) = rows["/world/object/shape"]
    assert shape["Boxes3D:half_sizes"] == [pytest.approx([0.04, 0.04, 0.05])]
    # The hand at each wrist goal; the goals accumulate; contacts of this grasp and all.
    hand = rows["/world/object/hand"]
    assert [r["Transform3D:translation"][0] for r in hand] == [
        pytest.approx([0.1 * k, -0.05, 0.12]) for k in (1, 2, 3)
    ]
    assert [len(r["Points3D:positions"]) for r in rows["/world/object/wrist_goals"]] == [1, 2, 3]
    last = rows["/world/object/contacts"][-1]["Points3D:positions"]
    assert last == [pytest.approx([0.03, 0.02, 0.03]), pytest.approx([-0.02, 0.0, 0.04])]
    assert [len(r["Points3D:positions"]) for r in rows["/world/object/contacts_all"]] == [2, 4, 6]
    # The belief per class after every grasp, and the bars of the last.
    cup = [r["Scalars:scalars"] for r in rows["/belief/cup"]]
    assert cup == [[pytest.approx(0.5)], [pytest.approx(0.6)], [pytest.approx(0.7)]]
    (bars,) = rows["/belief_bars"][-1]["BarChart:values"]  # a tensor
    assert bars["shape"] == [3] and bars["buffer"] == pytest.approx([0.7, 0.3, 0.0])
    status = [r for r in rows["/status"] if r.get("grasp") == 3]
    assert "grasp** 3" in status[0]["TextDocument:text"][0]


def test_a_new_recognition_clears_the_last_and_a_library_mesh_is_used(tmp_path: Path) -> None:
    verts = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]], dtype=np.float32)
    faces = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]], dtype=np.uint32)
    asked: list[str] = []

    def meshes(name: str) -> tuple[np.ndarray, np.ndarray] | None:
        asked.append(name)
        return (verts, faces) if name == "cup" else None

    rec, mem, scene = _memory_scene(meshes=meshes)
    scene.on_progress(_progress(1, "s1"))
    scene.on_progress(_progress(2, "s1"))
    scene.on_progress(_progress(1, "s2", object="sphere", extents=(0.1, 0.1, 0.1)))
    rec.flush()
    rows = _read_back(mem, tmp_path)
    assert scene.sessions == ["s1", "s2"] and asked == ["cup", "sphere"]
    shapes = rows["/world/object/shape"]
    mesh = [r for r in shapes if "Mesh3D:vertex_positions" in r]
    assert len(mesh) == 1 and len(mesh[0]["Mesh3D:vertex_positions"]) == 4
    boxes = [r for r in shapes if "Boxes3D:half_sizes" in r]
    assert boxes[0]["grasp"] == 3 and boxes[0]["Boxes3D:half_sizes"] == [pytest.approx([0.05] * 3)]
    # The second recognition starts clean: a recursive clear, then its own goals only.
    clears = [r["grasp"] for r in rows["/world/object"] if "Clear:is_recursive" in r]
    assert clears == [1, 3]
    assert len(rows["/world/object/wrist_goals"][-1]["Points3D:positions"]) == 1


def test_progress_of_an_older_daemon_still_shows(tmp_path: Path) -> None:
    """A daemon from before the view's fields: the object where [workcell] puts it, the top
    three as the belief, no contacts."""
    old = b'{"v":1,"session_id":"old","move":1,"pose":{"v":1,"xyz":[0.1,0,0.1],"quat":[0,0,0,1]},'
    old += b'"n_contacts":0,"top3":[["cup",0.6],["a/b c",0.4]]}'
    msg = m.decode(old, m.Progress)
    assert msg.contacts == [] and msg.belief == [] and msg.object_pose is None
    rec, mem, scene = _memory_scene()
    scene.on_progress(msg)
    rec.flush()
    rows = _read_back(mem, tmp_path)
    assert f"/belief/{entity_name('a/b c')}" in rows and "/belief/cup" in rows
    assert "/belief_bars" not in rows
    placed = [r for r in rows["/world/object"] if "Transform3D:translation" in r]
    assert placed[0]["Transform3D:translation"][0] == pytest.approx(WorkcellConfig().object_xyz)
    assert rows["/world/object/contacts"][0].get("Points3D:positions") in (None, [])


def test_the_new_progress_fields_are_left_out_while_empty() -> None:
    """Clients from before the view's fields refuse unknown fields: a Progress without them
    encodes as before; with them it round-trips."""
    plain = m.Progress(session_id="s", move=1, pose=None, n_contacts=0, top3=[])
    keys = set(json.loads(m.encode(plain)))
    assert not keys & {"contacts", "belief", "object_pose", "object", "extents"}
    full = _progress(2)
    assert m.decode(m.encode(full), m.Progress) == full


def test_library_meshes_reads_the_data_dirs_objects(trained_home: Path) -> None:
    load = library_meshes(paths.objects_dir(trained_home))
    mesh = load("cup")
    assert mesh is not None and mesh[0].shape[1] == 3 and mesh[1].shape[1] == 3
    assert load("no-such-object") is None


# --------------------------------------------------------------------------- against the daemon


def _run_recognition(ep: str, request: m.RecognizeRequest, out: dict) -> threading.Thread:
    def run() -> None:
        try:
            with open_client([ep], FAKE_ROBOT, timeout=30.0) as client:
                out["progress"] = []
                out["result"] = client.recognize(
                    request, on_progress=out["progress"].append, timeout=WAIT_S
                )
        except BaseException as e:  # reported by the test
            out["error"] = e

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


def _pump_until_done(feed: ProgressFeed, t: threading.Thread, out: dict) -> None:
    """Pump the feed (this thread logs) until the recognition ended and all its grasps came."""
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        feed.pump(0.2)
        if not t.is_alive():
            if "error" in out:
                raise out["error"]
            if feed.delivered >= out["result"].moves:
                return
    raise AssertionError(
        f"after {WAIT_S:.0f} s: recognition alive={t.is_alive()}, "
        f"{feed.delivered} grasps delivered, out={sorted(out)}"
    )


def test_the_feed_logs_every_grasp_of_a_daemon_recognition(
    start_fake_daemon, trained_home: Path, tmp_path: Path
) -> None:
    _daemon, ep = start_fake_daemon()
    rec, mem, scene = _memory_scene(meshes=library_meshes(paths.objects_dir(trained_home)))
    seen: list[m.Progress] = []

    def on_progress(msg: m.Progress) -> None:
        seen.append(msg)
        scene.on_progress(msg)

    with ZenohSession(client_settings([ep])) as zs:
        feed = ProgressFeed(zs.session, FAKE_ROBOT, on_progress)
        out: dict = {}
        req = m.RecognizeRequest(policy="random", max_moves=4, seed=3, object="cup")
        t = _run_recognition(ep, req, out)
        try:
            _pump_until_done(feed, t, out)
        finally:
            t.join(WAIT_S)
            feed.close()
    res = out["result"]
    assert res.moves >= 1 and feed.rejected == 0
    assert [p.move for p in seen] == list(range(1, res.moves + 1))
    assert {p.session_id for p in seen} == {res.session_id}
    assert scene.grasps == res.moves and scene.sessions == [res.session_id]
    # The daemon filled the view's fields: placement, object, extents, full belief.
    for p in seen:
        assert p.object == "cup" and p.extents is not None and p.object_pose is not None
        assert len(p.contacts) <= p.n_contacts
        if p.top3:
            assert sorted(label for label, _ in p.belief) == sorted(["cup", "sphere", "bottle"])
            assert sum(v for _, v in p.belief) == pytest.approx(1.0, abs=1e-6)
    assert any(p.contacts for p in seen)
    rec.flush()
    rows = _read_back(mem, tmp_path)
    assert [r["grasp"] for r in rows["/world/object/hand"]] == list(range(1, res.moves + 1))
    assert [r["grasp"] for r in rows["/world/object/contacts"]] == list(range(1, res.moves + 1))
    (shape,) = rows["/world/object/shape"]
    assert "Mesh3D:vertex_positions" in shape  # the cup's mesh from the data directory
    n_all = len(rows["/world/object/contacts_all"][-1]["Points3D:positions"] or [])
    assert n_all == sum(len(p.contacts) for p in seen)


def test_view_without_rerun_says_how_to_install_it(monkeypatch, capsys) -> None:
    from activetouch.cli.main import main

    monkeypatch.setitem(sys.modules, "rerun", None)  # import rerun -> ImportError
    assert main(["view", "--port", str(free_port())]) == 2
    err = capsys.readouterr().err
    assert "pip install 'activetouch[view]'" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_the_server_listens_on_loopback_only() -> None:
    import subprocess

    with RerunServer(free_port()) as server:
        pid = server.pid
        out = subprocess.run(["ss", "-Hltnp"], capture_output=True, text=True).stdout
        local = [line.split()[3] for line in out.splitlines() if f"pid={pid}," in line]
        assert f"127.0.0.1:{server.grpc_port}" in local and len(local) == 2, out  # + its web
        assert all(addr.startswith("127.0.0.1:") for addr in local), local
        page = [line.split()[3] for line in out.splitlines() if f":{server.web_port} " in line]
        assert page == [f"127.0.0.1:{server.web_port}"], out  # ours, in this process
        assert server.viewer_url.startswith(f"http://127.0.0.1:{server.web_port}/?url=")
    assert server.proc.poll() is not None


def test_the_view_command_serves_the_page_and_stops_on_sigterm(
    start_fake_daemon, trained_home: Path
) -> None:
    """`activetouch view` as its own process: it prints the address, serves the viewer's page
    with the loopback-only policy, and on SIGTERM stops with its Rerun server."""
    import queue
    import signal
    import subprocess
    import urllib.request

    from activetouch.view.live import _listening

    _daemon, ep = start_fake_daemon()
    port, grpc = free_port(), free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "activetouch", "view", "--connect", ep, "--robot", FAKE_ROBOT,
         "--port", str(port), "--grpc-port", str(grpc), "--data", str(trained_home)],
        cwd=ROOT, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
        text=True,
    )  # fmt: skip
    lines: queue.SimpleQueue[str] = queue.SimpleQueue()
    reader = threading.Thread(
        target=lambda: [lines.put(line) for line in proc.stderr or ()], daemon=True
    )
    reader.start()
    try:
        deadline, said = time.monotonic() + WAIT_S, ""
        while "open http://" not in said and time.monotonic() < deadline:
            assert proc.poll() is None, f"view exited with {proc.returncode}: {said}"
            with suppress(queue.Empty):
                said += lines.get(timeout=1.0)
        assert f"open http://127.0.0.1:{port}/?url=" in said, said
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=30) as r:
            csp = r.headers["Content-Security-Policy"]
            page = r.read()
        assert b"re_viewer.js" in page
        assert f"connect-src 'self' http://127.0.0.1:{grpc} " in csp
        assert _listening(grpc)
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            rc = proc.wait(60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(30)
    assert rc == 0
    assert not _listening(port) and not _listening(grpc)


# --------------------------------------------------------------------------- in a real browser


def _nontrivial(png: bytes) -> tuple[bool, str]:
    """The viewer has drawn the scene: many colours, none covering almost everything, and the
    colours of the table (brown), of the object and wrist goals (blues) and of the belief bars
    (green) all present, so the data has arrived, not only the empty panels."""
    from PIL import Image

    a = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).reshape(-1, 3).astype(np.int32)
    colours, counts = np.unique(a, axis=0, return_counts=True)
    dominant = counts.max() / len(a)
    r, g, b = a[:, 0], a[:, 1], a[:, 2]
    brown = float(np.mean((r > g + 15) & (g > b + 10) & (r > 90)))
    blue = float(np.mean((b > r + 25) & (b > 150)))
    green = float(np.mean((g > r + 20) & (g > b + 40)))
    ok = len(colours) > 500 and dominant < 0.8 and brown > 0.02 and blue > 0.001 and green > 0.005
    return ok, (
        f"{len(colours)} colours, dominant {dominant:.2f}, table brown {brown:.3f}, "
        f"object/goal blue {blue:.4f}, bar green {green:.4f}"
    )


@pytest.mark.slow
def test_the_served_viewer_shows_a_recognition_in_headless_chromium(
    start_fake_daemon, trained_home: Path, tmp_path: Path
) -> None:
    """The browser opens the viewer while a slow recognition (1 s per grasp, never confident)
    runs; once a screenshot shows the scene drawn, with grasps logged and the recognition still
    running, the recognition is cancelled."""
    from tests.chromium import Browser, chromium_path

    if chromium_path() is None:
        pytest.skip("no chromium on this machine (apt-get install chromium)")
    pytest.importorskip("PIL")
    _daemon, ep = start_fake_daemon(["session.stable_grasps=1000", "hand.close_s=1.0"])
    with RerunServer(free_port()) as server:
        rec = rr.RecordingStream("activetouch", recording_id="browser-test")
        rec.connect_grpc(server.grpc_url)
        scene = SceneLogger(rec, WorkcellConfig(), library_meshes(paths.objects_dir(trained_home)))
        scene.start()
        with ZenohSession(client_settings([ep])) as zs:
            feed = ProgressFeed(zs.session, FAKE_ROBOT, scene.on_progress)
            out: dict = {}
            req = m.RecognizeRequest(
                policy="random", max_moves=1000, seed=1, object="cup", session_id="browser"
            )
            t = _run_recognition(ep, req, out)
            browser = Browser(server.viewer_url, width=1280, height=720)
            try:
                deadline = time.monotonic() + WAIT_S
                png, ok, why, during = b"", False, "", False
                while time.monotonic() < deadline and t.is_alive():
                    feed.pump(0.0)
                    if scene.grasps >= 6:
                        rec.flush()
                        png = browser.screenshot()
                        ok, why = _nontrivial(png)
                        during = t.is_alive()
                        if ok:
                            break
                    time.sleep(0.5)
                # For the figure: a few more looks for a moment the viewer has caught up
                # (two screenshots alike) while the recognition still runs; not required.
                for _ in range(6 if ok else 0):
                    time.sleep(0.5)
                    feed.pump(0.0)
                    again = browser.screenshot()
                    if not t.is_alive() or not _nontrivial(again)[0]:
                        break
                    if again == png:
                        break
                    png = again
                (tmp_path / "view.png").write_bytes(png)
                assert ok, f"the viewer did not draw the scene within {WAIT_S:.0f} s: {why}"
                assert during, "the recognition ended before the screenshot"
                # The page reached nothing but loopback: whatever else Rerun's page asks for
                # (fonts, its release check, its telemetry) the served page's CSP blocks.
                browser.screenshot()  # the events so far read in
                away = {
                    rid: u
                    for rid, u in browser.requested.items()
                    if not u.startswith(("http://127.0.0.1:", "data:", "blob:"))
                }
                assert browser.requested, "no request seen"
                unblocked = {u for rid, u in away.items() if browser.blocked.get(rid) != "csp"}
                assert not unblocked, unblocked
                with open_client([ep], FAKE_ROBOT, timeout=30.0) as client:
                    client.cancel("browser")  # (it may have run out of poses meanwhile)
                _pump_until_done(feed, t, out)
            finally:
                browser.close()
                t.join(WAIT_S)
                feed.close()
            assert browser.proc.poll() is not None
        rec.disconnect()
    res = out["result"]
    assert res.stop_reason in ("cancelled", "exhausted") and scene.grasps == res.moves >= 5
    figure = ROOT / "docs" / "figures" / "view.png"
    if figure.parent.is_dir() and not figure.exists():
        figure.write_bytes(png)  # the docs' figure, made once (delete it to make it again)
