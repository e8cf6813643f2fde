"""What the live view shows, from the daemon's published messages only (no physics here).

`SceneLogger` turns decoded messages into Rerun log calls on a recording stream (a
`rr.RecordingStream`, or any object with its `log` / `set_time` / `send_blueprint`: tests pass
a memory recording or a double). It keeps no Zenoh or server state, so it is tested without a
network. Every call must come from one thread (Rerun's timeline is per thread).

Entities (the base frame `world` is the robot's base frame, z up, metres):

| entity | what (when: `*` every grasp) |
|---|---|
| `world/table` | the table, a box from `[workcell]` (once, static) |
| `world/object` | the object frame in the base frame: the recognition's placement * |
| `world/object/shape` | the object: its library mesh, else a box of its extents (new object) |
| `world/object/hand` | the wrist goal of this grasp (object frame); `palm`, `axes` under it * |
| `world/object/contacts` | this grasp's contacts (object frame) * |
| `world/object/contacts_all` | every contact of the recognition so far * |
| `world/object/wrist_goals` | the wrist goals so far; `path` the line through them * |
| `belief/<class>` | p(class) after the grasp (a time series) * |
| `belief_bars` | the same as a bar chart, classes in the model's order * |
| `status` | recognition, grasp, top classes (markdown) * |

Timelines: `grasp` counts the grasps this view has seen (across recognitions, so they do
not overlap), `move` is the grasp's number in its recognition, `stamp` the daemon's wall clock.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from contextlib import suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from activetouch.config import WorkcellConfig
from activetouch.errors import DataError
from activetouch.objects.library import ObjectLibrary
from activetouch.sim.render import read_obj
from activetouch.transport.messages import Progress

TABLE_COLOUR = (150, 120, 90, 255)
OBJECT_COLOUR = (170, 190, 215, 255)
HAND_COLOUR = (60, 60, 70, 255)
CONTACT_COLOUR = (230, 40, 40, 255)
PAST_CONTACT_COLOUR = (240, 160, 60, 255)
GOAL_COLOUR = (60, 120, 230, 255)
GOAL_PATH_COLOUR = (60, 120, 230, 110)
PALM_HALF_SIZES = (0.045, 0.035, 0.012)  # a ReFlex palm, roughly (hand frame, metres)
AXIS_LENGTH = 0.06
EYE_OFFSET = np.array([0.55, -0.45, 0.40])  # the camera, from the object (metres)

_UNSAFE = re.compile(r"[^A-Za-z0-9_.\-]")


def entity_name(label: str) -> str:
    """`label` as one entity-path part (anything but letters, digits, `_ . -` becomes `_`)."""
    return _UNSAFE.sub("_", label) or "_"


MeshLoader = Callable[[str], tuple[np.ndarray, np.ndarray] | None]


def library_meshes(objects_dir: Path) -> MeshLoader:
    """A loader of the object library's visual meshes (vertices, triangles) by object name;
    None for an object the library under `objects_dir` does not have."""

    lib = ObjectLibrary(objects_dir)

    def load(name: str) -> tuple[np.ndarray, np.ndarray] | None:
        try:
            spec = lib.get(name)
            verts, faces = read_obj(spec.visual_mesh)
        except (DataError, OSError, ValueError):
            return None
        return np.asarray(verts, dtype=np.float32), np.asarray(faces, dtype=np.uint32)

    return load


@dataclass
class _Session:
    session_id: str
    object: str | None = None
    extents: tuple[float, float, float] | None = None
    goals: list[np.ndarray] = field(default_factory=list)
    contacts: list[np.ndarray] = field(default_factory=list)
    moves: list[int] = field(default_factory=list)
    shape_logged: bool = False


def blueprint(workcell: WorkcellConfig | None = None) -> rrb.Blueprint:
    """The viewer's layout: the 3-D scene beside the belief (time series, bars) and status;
    the camera on the object (where [workcell] puts it), the `grasp` timeline selected."""
    view3d: dict[str, Any] = {"origin": "world", "name": "workcell"}
    extra: list[Any] = []
    with suppress(AttributeError, TypeError):  # newer Rerun only: keep the default otherwise
        target = np.asarray((workcell or WorkcellConfig()).object_xyz, dtype=np.float64)
        view3d["eye_controls"] = rrb.EyeControls3D(
            position=(target + EYE_OFFSET).tolist(), look_target=target.tolist()
        )
    with suppress(AttributeError, TypeError):
        extra.append(rrb.TimePanel(timeline="grasp", state="collapsed"))
    try:
        view = rrb.Spatial3DView(**view3d)
    except TypeError:
        view = rrb.Spatial3DView(origin="world", name="workcell")
    return rrb.Blueprint(
        rrb.Horizontal(
            view,
            rrb.Vertical(
                rrb.TimeSeriesView(origin="belief", name="belief per class"),
                rrb.BarChartView(origin="belief_bars", name="belief now (model's class order)"),
                rrb.TextDocumentView(origin="status", name="status"),
            ),
            column_shares=[3, 2],
        ),
        *extra,
        collapse_panels=True,
    )


class SceneLogger:
    """Logs the workcell, and each published grasp, to `rec` (see the module)."""

    def __init__(
        self,
        rec: Any,
        workcell: WorkcellConfig,
        meshes: MeshLoader | None = None,
        send_blueprint: bool = True,
    ) -> None:
        self.rec = rec
        self.workcell = workcell
        self.meshes = meshes
        self.grasps = 0  # grasps logged (the `grasp` timeline)
        self.sessions: list[str] = []  # recognitions seen, in order
        self._session: _Session | None = None
        self._mesh_cache: dict[str, tuple[np.ndarray, np.ndarray] | None] = {}
        self._send_blueprint = send_blueprint
        self._started = False

    # ------------------------------------------------------------------ static scene

    def start(self) -> None:
        """The scene that does not change: axes convention, the table, the layout."""
        if self._started:
            return
        self._started = True
        if self._send_blueprint and hasattr(self.rec, "send_blueprint"):
            self.rec.send_blueprint(blueprint(self.workcell))
        self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        wc = self.workcell
        self.rec.log(
            "world/table",
            rr.Boxes3D(
                centers=[list(map(float, wc.table_center))],
                half_sizes=[[float(s) / 2 for s in wc.table_size]],
                colors=[TABLE_COLOUR],
                fill_mode="solid",
            ),
            static=True,
        )
        self.rec.log(
            "status", rr.TextDocument("waiting for a recognition ...", media_type="text/markdown")
        )

    # ------------------------------------------------------------------ per grasp

    def on_progress(self, msg: Progress) -> None:
        """One grasp of a recognition, as the daemon published it."""
        self.start()
        s = self._session
        if s is None or s.session_id != msg.session_id:
            s = self._session = _Session(msg.session_id)
            self.sessions.append(msg.session_id)
            new_session = True
        else:
            new_session = False
        self.grasps += 1
        self.rec.set_time("grasp", sequence=self.grasps)
        self.rec.set_time("move", sequence=int(msg.move))
        if msg.stamp > 0:
            self.rec.set_time("stamp", timestamp=float(msg.stamp))
        if new_session:
            # The last recognition's goals, contacts and classes go; the table stays.
            self.rec.log("world/object", rr.Clear(recursive=True))
            self.rec.log("belief", rr.Clear(recursive=True))
        self._log_object(s, msg)
        s.moves.append(int(msg.move))
        if msg.pose is not None:
            xyz = np.asarray(msg.pose.xyz, dtype=np.float64)
            quat = _unit(msg.pose.quat)
            s.goals.append(xyz)
            self.rec.log(
                "world/object/hand",
                rr.Transform3D(translation=xyz.tolist(), quaternion=rr.Quaternion(xyzw=quat)),
            )
            if len(s.goals) == 1:  # the session's first: the hand's shape under it
                self._log_hand_shape()
            goals = np.vstack(s.goals)
            self.rec.log(
                "world/object/wrist_goals",
                rr.Points3D(goals, radii=0.005, colors=[GOAL_COLOUR]),
            )
            self.rec.log(
                "world/object/wrist_goals/path",
                rr.LineStrips3D([goals], colors=[GOAL_PATH_COLOUR], radii=0.001),
            )
        pts = np.asarray(msg.contacts, dtype=np.float64).reshape(-1, 3)
        s.contacts.append(pts)
        self.rec.log(
            "world/object/contacts", rr.Points3D(pts, radii=0.005, colors=[CONTACT_COLOUR])
        )
        every = np.vstack(s.contacts)
        self.rec.log(
            "world/object/contacts_all",
            rr.Points3D(every, radii=0.003, colors=[PAST_CONTACT_COLOUR]),
        )
        self._log_belief(msg)
        self.rec.log("status", rr.TextDocument(_status_text(msg), media_type="text/markdown"))

    def _log_object(self, s: _Session, msg: Progress) -> None:
        if msg.object_pose is not None:
            self.rec.log(
                "world/object",
                rr.Transform3D(
                    translation=list(msg.object_pose.xyz),
                    quaternion=rr.Quaternion(xyzw=_unit(msg.object_pose.quat)),
                ),
            )
        else:  # an older daemon: the object frame of [workcell]
            yaw = np.radians(float(self.workcell.object_yaw_deg))
            self.rec.log(
                "world/object",
                rr.Transform3D(
                    translation=[float(v) for v in self.workcell.object_xyz],
                    quaternion=rr.Quaternion(xyzw=[0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)]),
                ),
            )
        extents = tuple(msg.extents) if msg.extents is not None else None
        if s.shape_logged and msg.object == s.object and extents == s.extents:
            return  # the same object as at the last grasp: its shape is logged
        s.object, s.extents, s.shape_logged = msg.object, extents, True
        mesh = self._mesh(msg.object)
        label = [msg.object or "object"]
        if mesh is not None:
            verts, faces = mesh
            self.rec.log(
                "world/object/shape",
                rr.Mesh3D(
                    vertex_positions=verts,
                    triangle_indices=faces,
                    albedo_factor=OBJECT_COLOUR,
                ),
            )
        elif extents is not None:
            self.rec.log(
                "world/object/shape",
                rr.Boxes3D(
                    half_sizes=[[e / 2 for e in extents]],
                    colors=[OBJECT_COLOUR],
                    fill_mode="solid",
                    labels=label,
                ),
            )
        else:
            self.rec.log("world/object/shape", rr.Clear(recursive=False))

    def _mesh(self, name: str | None) -> tuple[np.ndarray, np.ndarray] | None:
        if name is None or self.meshes is None:
            return None
        if name not in self._mesh_cache:
            self._mesh_cache[name] = self.meshes(name)
        return self._mesh_cache[name]

    def _log_hand_shape(self) -> None:
        self.rec.log(
            "world/object/hand/palm",
            rr.Boxes3D(
                half_sizes=[PALM_HALF_SIZES],
                centers=[[0.0, 0.0, -PALM_HALF_SIZES[2]]],
                colors=[HAND_COLOUR],
                fill_mode="solid",
            ),
        )
        self.rec.log(
            "world/object/hand/axes",
            rr.Arrows3D(
                origins=np.zeros((3, 3)),
                vectors=np.eye(3) * AXIS_LENGTH,
                colors=[(220, 40, 40), (40, 200, 40), (40, 80, 230)],
            ),
        )

    def _log_belief(self, msg: Progress) -> None:
        belief: Sequence[tuple[str, float]] = msg.belief or msg.top3  # top3: an older daemon
        for label, p in belief:
            self.rec.log(f"belief/{entity_name(label)}", rr.Scalars(float(p)))
        if msg.belief:
            self.rec.log(
                "belief_bars", rr.BarChart(np.array([p for _, p in msg.belief], dtype=np.float64))
            )


def _unit(quat: Sequence[float]) -> list[float]:
    q = np.asarray(quat, dtype=np.float64)
    return (q / np.linalg.norm(q)).tolist()


def _status_text(msg: Progress) -> str:
    top = ", ".join(f"{label} {p:.2f}" for label, p in msg.top3) or "nothing felt yet"
    lines = [
        f"**recognition** `{msg.session_id}`" + (f" — object `{msg.object}`" if msg.object else ""),
        "",
        f"**grasp** {msg.move} · {msg.n_contacts} contacts · skipped {msg.skipped}",
        "",
        f"**top classes** {top}",
    ]
    if msg.belief:
        lines += ["", "| class | p |", "|---|---|"]
        lines += [f"| {label} | {p:.3f} |" for label, p in msg.belief]
    return "\n".join(lines)
