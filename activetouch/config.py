"""One source of truth for parameters: typed sections, loaded from TOML, overridable on the CLI.

Each part owns a section dataclass here; `Config` composes them. `load_config(path, overrides)`
validates types and names and raises `ConfigError` naming the offending key.
Defaults are the papers' values (Zhang et al. IROS 2016/2017) unless stated.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import re
import tomllib
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from activetouch.device_types import device_config
from activetouch.errors import ConfigError
from activetouch.settings import apply_section

log = logging.getLogger(__name__)


# Settings that take one of a few words: anything else is refused when the config is loaded.
Classifier = Literal["svm", "nn_inner", "nn_intersection"]
Belief = Literal["histogram", "grasp_likelihood", "pose"]
Granularity = Literal["triangle", "grasp"]
ActionFrame = Literal["relative", "absolute"]
PolicyName = Literal["tree", "greedy", "random", "mesh"]
Eq4Sampling = Literal["renormalise", "per_class"]
Objective = Literal["final", "anytime", "info_gain"]
MovementCost = Literal["pose", "travel_time"]
GridLayout = Literal["shared", "per_object"]
CellsFrom = Literal["library", "setting"]
Sensing = Literal["tactile", "stall"]
ZenohMode = Literal["peer", "client"]
Ros2Attachment = Literal["gid", "legacy"]
Profile = Literal["robust", "paper"]

# Named sets of settings, applied over the defaults before the file and the overrides (which
# still win). "robust" is the defaults: the configuration measured best in the twin under the
# real robot's errors (docs/benchmark.md, "The default profile"). "paper" is the method of
# Jiang et al. as docs/results/sim reproduces it: the histogram classifier on the bag of
# triangles, the object pose taken as known.
PROFILES: dict[str, dict[str, Any]] = {
    "robust": {},
    "paper": {
        "recognition.belief": "histogram",
        "observation.cells_from": "setting",
        "session.average_readings": 0,
    },
}


@dataclass
class RecognitionConfig:
    # Triangle parameterisation: three of l0, l1, l2 (sides, l0 largest) and a0, a1, a2 (angles).
    parameterisation: str = "l0,l1,a0"
    bins: int = 10  # per histogram dimension
    # Degenerate triangles are dropped: a side shorter than this (duplicate points) ...
    min_side_m: float = 1e-4
    # ... or an angle smaller than this (collinear points).
    min_angle_deg: float = 1.0
    classifier: Classifier = "svm"  # svm | nn_inner | nn_intersection
    # Partial-observation training samples per object (random subsets of its grasps).
    partial_samples_per_object: int = 200
    partial_min_grasps: int = 1
    partial_max_grasps: int = 30
    # Contacts this close to the support plane (or below it) are the table, not the object.
    support_margin_m: float = 0.005
    seed: int = 0
    # What the session's p(y | ...) is (read when recognising, so eval can switch it):
    # "histogram" (the paper: the classifier on the histogram of every triangle so far),
    # "grasp_likelihood" (Bayes over grasps, each weighed by p(grasp | y, wrist pose) from the
    # training grasps near that pose; recognition/grasp_likelihood.py) or "pose" (the default:
    # Bayes over class x where the object really stands, below; measured best under the real
    # robot's errors, docs/benchmark.md "The default profile"). The kernel widths (sensor
    # scale and finger-angle width tuned on the hard library's seeds 100-119; the pose width
    # 1.5 cm, 2 before, on its seeds 100-109 under all errors: +0.18 grasps, 97.3 against 96.7 %):
    belief: Belief = "pose"
    likelihood_pose_sigma_m: float = 0.015
    likelihood_pose_sigma_deg: float = 12.0
    likelihood_sensor_scale: float = 1.0
    likelihood_angle_sigma_rad: float = 0.05
    # The least p(grasp | y, pose) a class is given: one grasp then costs a class at most
    # log(1 / floor) nats. 0.03, tuned on the hard library under all errors, seeds 100-109
    # (1e-4 / 0.01 / 0.03 / 0.1: 91.2 / 91.8 / 94.8 / 93.3 %; docs/benchmark.md).
    likelihood_floor: float = 0.03
    # "pose": a belief over class x where the object really stands (dx, dy on the table and a
    # yaw about its vertical, on a grid over +-range), each grasp weighed with the class's
    # mesh: contacts on its surface, sensor sites and swept fingers outside it
    # (recognition/pose_belief.py). The planner plans on its class marginal.
    pose_range_m: float = 0.03
    pose_step_m: float = 0.01
    pose_range_deg: float = 30.0
    pose_step_deg: float = 7.5
    # A contact's spread about the surface, no finer than the hypotheses' 1 cm grid: at 5 mm a
    # class's likelihood peaked between grid points, and a class whose yaw swings its body
    # about an off-centre origin (a handle mug) found a hypothesis nearer that peak than a
    # round look-alike could, and drew the misses (hard library, tuning seeds: 81.8 % at 5 mm,
    # 86.4 % at 1 cm; docs/benchmark.md).
    pose_contact_sigma_m: float = 0.01
    # Where a contact's sensor site lies off the surface it touches, on average: outside, as
    # the site sits under the skin and the skin spreads a touch to the sites beside it (the
    # training grasps' contacts: 1.8 mm at the median). Tuned (docs/results/robust).
    pose_contact_offset_m: float = 0.002
    # Weigh each class standing on the table (its frame lifted so its base meets the table)
    # rather than centred at the frame the wrist poses are given in, the true object's: a
    # class 1 cm taller then has its top 1 cm higher, as on the robot. Tuned.
    pose_on_table: bool = True
    pose_free_margin_m: float = 0.003
    pose_free_sigma_m: float = 0.004
    pose_floor: float = 1e-3
    # A Gaussian prior over the hypotheses (0: uniform over the grid): small offsets are
    # likelier than large ones, so a look-alike turned far to hide its difference pays for it.
    pose_prior_sigma_m: float = 0.0
    pose_prior_sigma_deg: float = 0.0
    # Between grasps the object may slide on the table (a lone finger pushes a free-standing
    # object): before each grasp after the first, the placement belief spreads by a Gaussian
    # of this standard deviation in x and y. 0 (the default): the object stays where it
    # stood, as the paper's fixed objects; 0.003 for free-standing ones (hard library, nudged
    # up to 1 cm per grasp: +7 points; the object fixed: -0.6, not significant; docs/benchmark.md).
    pose_drift_m: float = 0.0
    # Grasp where the object is believed to stand: each grasp's wrist pose is its training
    # pose placed where the mesh's term of the pose belief says the object stands after the
    # grasps so far (`PoseBelief.placement_peak`), not on the nominal placement, so a
    # misplaced object is grasped where training grasped it and the training grasps' term can
    # tell look-alikes apart again (docs/benchmark.md).
    pose_follow: bool = True
    # ... and every other grasp where a rival group of classes puts it, when that placement has
    # at least this share of the first's support (`rival_placement`; 0: never). Each class's
    # training grasps read sharp only on its own frame's poses, so grasps all placed for three
    # handle mugs took a plain mug's runs; shared, neither frame has the edge (hard library,
    # all errors, tuning seeds 100-109: 96.7 % against 94.8 %; docs/benchmark.md). The
    # support is the mesh's term's or the whole belief's, whichever gives the rival more.
    pose_alternate_share: float = 0.5
    # ... plus the training grasps' likelihood at the wrist pose each hypothesis implies
    pose_with_grasps: bool = True
    # That term's weight against the mesh's (log scale). Tuned on the hard library under all
    # errors, seeds 100-104: 1 / 2 / 3 / 4 gave 89.7 / 92.7 / 90.9 / 89.7 % (docs/benchmark.md).
    pose_grasps_weight: float = 2.0
    # With the pose belief, the planner judges what a grasp will tell as if the object stood
    # anywhere within +-plan_placement_m (x, y) / +-plan_placement_deg (yaw) of where it is
    # believed: each training grasp's evidence is averaged over those placements
    # (`GraspLikelihood.training_log_likelihoods(offsets=...)`), so a grasp whose feel
    # depends on where the object is counts for less. 0: the nominal placement.
    plan_placement_m: float = 0.0
    plan_placement_deg: float = 0.0


@dataclass
class ObservationConfig:
    # One observation is a whole grasp's triangles ("grasp", measured best in the twin:
    # docs/planner.md) or a single triangle ("triangle", the paper).
    granularity: Granularity = "grasp"
    translation_cell_m: float = 0.06
    # "library" (default): `train` makes the translation cells finer than translation_cell_m
    # (down to 1 cm) until the pooled poses send the hand at most max_pose_shift_m from where
    # a class was trained, so the cells follow the library's sizes (each size has its own grid
    # poses; measured on the hard library, docs/benchmark.md). "setting": translation_cell_m.
    cells_from: CellsFrom = "library"
    max_pose_shift_m: float = 0.015
    quaternion_cell: float = 0.05
    triangle_cell: float = 0.08
    # How an edge p -> q is keyed: "relative" (the paper: the discretised pose of q in p's
    # frame, pooled over objects) or "absolute" (the discretised nominal pose q itself: class y
    # answers with what its own grasp at, or near, q looked like; docs/planner.md). Absolute
    # is the default: with the shared grid every class has a grasp at every pose.
    action_frame: ActionFrame = "absolute"
    # "absolute" only: a class without a grasp at q's cell answers with its grasp nearest to q
    # if that lies within these (the objects' grids differ in radius, not in direction).
    absolute_near_m: float = 0.06
    absolute_near_deg: float = 10.0


@dataclass
class PlannerConfig:
    # Defaults measured in the twin (docs/planner.md, "The defaults: what beats random, and
    # why"); the paper's own settings are lam 0.5, 20 simulations, the whole path executed,
    # objective "final".
    policy: PolicyName = "tree"  # tree | greedy | random | mesh
    horizon: int = 5
    simulations: int = 200
    exploration_c: float = 1.0
    # Weight of the movement cost against misclassification (Eq. 1). The paper's 0.5 lets the
    # movement term rank the poses (greedy then always takes the nearest); 0 counts grasps.
    lam: float = 0.0
    # What c_m measures: "pose" (the paper: translation and rotation between the poses) or
    # "travel_time" (with an arm that estimates it, e.g. Baxter: the move's duration before
    # planning, over the longest move; docs/motion.md). Only matters with lam > 0.
    movement_cost: MovementCost = "pose"
    # Execute only the first pose of the path, then search again from the real grasp.
    replan_every_grasp: bool = True
    # Eq. 4 when some classes have no data for (action, cell): "renormalise" draws y among the
    # classes that have data; "per_class" draws y from the full p(y|h) and lets that class
    # back off to its action-only row, else observe nothing (docs/planner.md).
    eq4_sampling: Eq4Sampling = "renormalise"
    # The recognition term of Eq. 1: "final" (the paper) scores 1 - max p(y | h_T) at the
    # path's end only; "anytime" averages 1 - max p(y | h_t) over t = 1..T, so a path that is
    # confident after its first grasps beats one that only gets there by its last (with T = 1
    # both are Eq. 1). "info_gain": the mean over the path of H(p(y | h_t)) / log K, i.e. the
    # expected entropy reduction per step (docs/planner.md).
    objective: Objective = "anytime"
    # Eq. 4 draws the class that produces a simulated observation from p(y | h)^(1 / tau),
    # normalised: 1 is Eq. 4; above 1 the runners-up's observations are imagined more often,
    # so a path that would test the leading class is not scored as learning nothing when the
    # belief is confidently wrong (docs/benchmark.md).
    belief_temperature: float = 1.0
    # policy "mesh" (planning/mesh_lookahead.py): the likeliest (class, placement) hypotheses
    # it predicts each pose's grasp under, the width (rad per finger) within which predicted
    # closures count as the same, and how much the expected top-class probability must rise
    # over the belief's own before the meshes, not greedy on the training grasps, decide.
    mesh_hypotheses: int = 64
    mesh_sigma_rad: float = 0.05
    mesh_min_gain: float = 0.01


@dataclass
class GridConfig:
    """Training grid (paper Alg. 1): wrist poses on an ellipsoid around the object."""

    step_deg: float = 25.0  # ring and azimuth step (authors: 25 in simulation, 45 on the robot)
    margin_m: float = 0.06  # palm pad distance beyond the object's half extent
    palm_offset_m: float = 0.0896  # palm pad height above the hand frame origin
    min_elevation_deg: float = 0.0  # lowest ring; poses lower than this meet the table
    rolls_deg: list[float] = field(default_factory=lambda: [0.0, 90.0])
    # One preshape per nominal pose: actions are wrist poses only, so a pose with two preshapes
    # would be two observations under one action. Add 0.8 (spherical) as its own grid if wanted.
    preshape: float = 0.0
    min_wrist_height_m: float = 0.03  # hand frame origin above the table top
    # Shift of the hand along its own x axis so the approach axis passes between the pointer
    # fingers (x = +0.06) and the thumb (x = -0.03) instead of at the hand origin: 0.015 centres
    # it. 0 (the authors' layout) leaves the pointer fingers 6 cm off a narrow object
    # (docs/objects.md, "Small objects").
    center_offset_m: float = 0.0
    # "shared": every object is grasped at the union of all training objects' grids, so each
    # class has data at every pose the planner can choose at test time (the object, hence its
    # grid, is unknown then). "per_object": each object at its own grid only (the paper).
    layout: GridLayout = "shared"


@dataclass
class SimConfig:
    """PyBullet twin: tactile model, guarded close, hand geometry choices, world."""

    # Tactile model: each contact point's force = stiffness * penetration (a compliant skin);
    # the elastomer over the barometers spreads it to the sites of the same link with a
    # Gaussian of the point-site distance (1 right over a site); pressure = summed force *
    # pressure_per_newton + Gaussian noise, contact = pressure > threshold.
    contact_threshold: float = 20.0  # sensor units above zero offset (ReFlex driver default)
    noise_std: float = 2.0  # sensor units
    contact_stiffness_n_per_m: float = 2000.0
    pressure_per_newton: float = 50.0
    spread_sigma_m: float = 0.005  # load spreading in the skin (site pitch 0.0079)
    # Noise stream: "pose" seeds each grasp from (seed, wrist pose, preshape), so a grasp does
    # not depend on what ran before (resumable collections repeat exactly); "stream" draws
    # from one generator per hand seeded once.
    noise_mode: str = "pose"
    seed: int = 0
    # Guarded close (ReFlex: 0.05 rad spool steps, each finger stops at its own first contact).
    spool_step_rad: float = 0.05
    substeps: int = 5  # collision checks inside the step where a finger first meets something
    # Tendon travel commanded past the last contact-free reading: the servo still runs to the
    # command it had when contact was sensed (reflex_base guarded_move commands the measured
    # spool + one step). 0: stop at the first sensed contact.
    post_contact_travel_rad: float = 0.05
    spool_limit_rad: float = 2.8  # tendon travel limit (tactile_triangles' Gazebo model)
    flexure_coupling: float = 0.25  # free finger: distal = k * proximal
    stall_depth_m: float = 0.003  # a link pushed this deep without a sensed contact is blocked
    skin_depth_m: float = 0.0015  # after a sensed contact: deepest press into the skin
    preshape_limit_rad: float = 1.6
    # The hand's robot time (the twin closes in milliseconds of wall time): a guarded close
    # takes one spool step per control period (the TakkTile driver steps at its 40 Hz packet
    # rate), opening and preshaping run at the servos' speed (MX-28 no load: ~5.8 rad/s).
    hand_period_s: float = 0.025
    finger_speed_rad_s: float = 5.0
    # What a grasp reports: "tactile" (the TakkTile's sensors over threshold) or "stall" (the
    # ReFlex SF, which has none: one contact per finger that stopped against the object, at its
    # distal sensor site `stall_contact_site`, as drivers/reflex/sf.py reports it).
    sensing: Sensing = "tactile"
    stall_contact_site: int = 6
    # Distal sensor sites (link frame); the visualiser URDF's by default. tactile_triangles'
    # Gazebo model: x = [0.0135, 0.0215, 0.0295, 0.0375], z = 0.009 each.
    distal_sensor_x: list[float] = field(default_factory=lambda: [0.0114, 0.0193, 0.0272, 0.0375])
    distal_sensor_z: list[float] = field(default_factory=lambda: [0.0129, 0.0129, 0.0129, 0.0073])
    # Proximal joint origin pitch: 0 (hardware-facts / older visualiser URDF: open fingers lie
    # flat, radially outwards) or 0.28 (newest visualiser URDF).
    proximal_zero_pitch_rad: float = 0.0
    # Spool angle of an open hand: 0 opens the fingers straight out, as the ReFlex does. Raising
    # them does not unblock training-grid poses (measured, paper's 7 objects, default grid: 42%
    # unreachable at 0 and 0.2, 45% at 0.5): the blocked poses are the 0 deg ring (the palm
    # housing itself dips under the table for objects < ~0.11 m tall) and the 25 deg ring at
    # roll 0, where the thumb points down at the table and raising it turns it further down.
    open_spool_rad: float = 0.0
    # Wrist (the table comes from [workcell]).
    wrist_penetration_tol_m: float = 0.002  # deeper hand/object or hand/table overlap: unreachable
    execute_step_m: float = 0.01  # collision-check spacing along executed wrist trajectories
    execute_step_rad: float = 0.05
    # The real robot's errors, for evaluation (docs/benchmark.md; 0 = none, the default). A
    # twin made for seed s stands the object off the workcell's placement by a uniform draw of
    # up to +-placement_error_m in x and y and +-placement_error_deg about z, while the wrist,
    # the session and the planner believe the nominal placement.
    placement_error_m: float = 0.0
    placement_error_deg: float = 0.0
    # Tactile faults (activetouch/recognition/faults.py): extra pressure noise (sensor units)
    # at every reading, sensors dead (read 0) and stuck (read over threshold) for the run, and
    # the per-grasp probability that a quiet sensor reports a spurious contact.
    fault_noise_std: float = 0.0
    fault_dead: int = 0
    fault_stuck: int = 0
    fault_spurious: float = 0.0
    # Calibration drift: each sensor's zero walks at a rate drawn within +-fault_sensor_drift
    # units per grasp after the session measured it; each finger's reported angle is off by a
    # draw within +-fault_finger_offset_rad, and its contacts with it.
    fault_sensor_drift: float = 0.0
    fault_finger_offset_rad: float = 0.0
    # The object nudged by a grasp: on opening, the hand's unbalanced push slides the object
    # by up to this far on the table (sim/nudge.py); the paper's objects were fixed.
    nudge_max_m: float = 0.0


# The real robot's errors the twin can add (SimConfig above; docs/benchmark.md).
SIM_ERROR_SETTINGS = (
    "placement_error_m",
    "placement_error_deg",
    "fault_noise_std",
    "fault_dead",
    "fault_stuck",
    "fault_spurious",
    "fault_sensor_drift",
    "fault_finger_offset_rad",
    "nudge_max_m",
)


@dataclass
class SessionConfig:
    """Recognition session (paper Alg. 2 around the planner): when to stop."""

    confidence: float = 0.6  # top class probability that counts as confident
    stable_grasps: int = 3  # ... for this many grasps in a row
    max_moves: int = 20  # grasps, the first random one included
    max_skips: int = 50  # unreachable poses tolerated before giving up
    # At the start, with the hand open: this many readings measure each sensor's rest level
    # and noise; a sensor in contact in most of them is ignored (stuck), and a contact counts
    # only above rest + noise_k sigma (or the hand's own threshold, whichever is higher).
    rest_readings: int = 20
    noise_k: float = 5.0
    # After each close, the fingers still on the object: this many new readings, and a contact
    # counts only if its sensor reads contact in all of them (a spike lasts one packet, a touch
    # stays). 0: the close's own reading alone.
    confirm_readings: int = 0
    # Where the noise at rest lifts the thresholds over the hand's own (the close's reading then
    # misses light contacts): after each close, the fingers still on the object, the contacts
    # are decided on the mean of this many new readings, over the hand's own threshold or
    # rest + noise_k sigma / sqrt(n), whichever is higher. 0: the close's own reading. Needs a
    # hand that tells its own thresholds and its sensors' sites; replaces confirm_readings.
    average_readings: int = 16
    # Before each grasp after the first, the hand open since the last close: this many
    # readings. A sensor in contact in most of them is ignored for the rest of the
    # recognition; every other sensor's contact threshold moves by its zero's walk since the
    # start (their mean against the start's, where beyond 3 standard errors: a barometer's
    # zero walks with temperature, and judged against the start's level a sensor walking
    # faster than its noise margin reads contact in every later grasp). 0 (the default): the
    # rest levels read at the start stand. Measured on the tuning seeds with 8, the twin's
    # drift (up to a unit a grasp) cost nothing either way, the readings 0.2 s a grasp
    # (docs/benchmark.md, "Re-zeroing before each grasp"); a hand whose zeros walk faster
    # wants it on.
    rezero_readings: int = 0


@dataclass
class ServiceConfig:
    """Recognition daemon (`activetouch serve`) and its Zenoh clients (docs/api.md)."""

    robot: str = "sim"  # one key chunk: everything lives under activetouch/<robot>/
    # Zenoh endpoints. Loopback only unless told otherwise; scouting is always off. The
    # default port is 7457, not Zenoh's 7447: a ROS 2 robot PC runs rmw_zenohd on
    # tcp/[::]:7447 (docs/api.md, "Running next to ROS 2").
    listen: list[str] = field(default_factory=lambda: ["tcp/127.0.0.1:7457"])
    connect: list[str] = field(default_factory=list)
    # "peer" (default): the daemon listens on `listen` and clients connect to it. "client": it
    # joins an existing Zenoh router (e.g. the lab's rmw_zenohd) named by `connect` and listens
    # on nothing (`listen` is ignored); its clients reach it through that router.
    zenoh_mode: ZenohMode = "peer"
    zenoh_config: str = ""  # Zenoh JSON5 file to start from (TLS, access control); "" none
    node_timeout_s: float = 5.0  # quick hand/arm calls (state, stop)
    motion_timeout_s: float = 60.0  # hand/arm motions (open, grasp, move)
    node_wait_s: float = 10.0  # at start: how long to wait for the hand/arm liveliness tokens
    # Devices that come and go (activetouch.daemon.supervision): the daemon starts without
    # them, tries to connect each every device_retry_s, probes a connected one every
    # device_check_s, and a probe failing for device_lost_after_s makes it lost (reconnected).
    device_retry_s: float = 2.0
    device_check_s: float = 0.5
    device_lost_after_s: float = 1.0
    request_timeout_s: float = 600.0  # clients: a recognition must finish within this
    state_hz: float = 20.0  # hand state / arm joint states publication rate
    # Recognitions that may wait while one runs (FIFO); 0: a second request gets a busy error.
    max_queued: int = 0
    shutdown_timeout_s: float = 2.0  # wait for the running recognition to stop on SIGTERM
    # Longest a plan may run: then it ends with the best path it has (the largest request
    # allowed, 20000 simulations at horizon 50, takes seconds; the default plan milliseconds).
    max_plan_s: float = 2.0
    # The twin's nodes sleep this long per motion (move, grasp), to emulate a real robot's
    # timing in demos and tests of cancel / shutdown; 0 runs the twin flat out.
    sim_motion_delay_s: float = 0.0


@dataclass
class RecordingConfig:
    """Every recognition (`recognize`, the daemon) written as MCAP under <data>/recordings/
    (docs/recordings.md); the oldest are deleted beyond these limits (0: no limit)."""

    enabled: bool = True
    max_total_mb: float = 1000.0
    max_age_days: float = 30.0

    def check(self) -> None:
        for name in ("max_total_mb", "max_age_days"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and v >= 0 and math.isfinite(v)):
                raise ConfigError(f"recording.{name} must be >= 0 (0: no limit), got {v}")


@dataclass
class Ros2Config:
    """The daemon's ROS 2 face over rmw_zenoh (activetouch/daemon/ros2_face.py, docs/api.md
    "ROS 2"): node ``<namespace>/activetouch`` on the daemon's own Zenoh session. Off by default."""

    enabled: bool = False
    domain_id: int = 0  # ROS_DOMAIN_ID of the ROS 2 graph to appear in (0-232)
    namespace: str = ""  # "" (the root) or "/name[/name...]": node <namespace>/activetouch
    # The rmw_zenoh attachment every request, reply and sample carries: "gid" (int64 sequence
    # number, int64 timestamp, length 16, 16-byte GID: 33 bytes; rmw_zenoh Jazzy >= 0.2.4,
    # Rolling >= 0.6.0) or "legacy" (the same values as labelled entries: older releases).
    # Requests are answered in the format they came in; this picks what the face sends first.
    attachment: Ros2Attachment = "gid"
    # TF frame ids: the robot base, the object frame (the workcell's placement), the hand.
    base_frame: str = "base"
    object_frame: str = "object"
    hand_frame: str = "hand"

    def check(self) -> None:
        if not 0 <= self.domain_id <= 232:
            raise ConfigError(f"ros2.domain_id must be 0-232 (ROS_DOMAIN_ID), got {self.domain_id}")
        ns = self.namespace
        if ns and not _ROS_NAMESPACE.fullmatch(ns):
            raise ConfigError(
                f'ros2.namespace {ns!r} is invalid: use "" or "/name[/name...]" with '
                "names of letters, digits and '_' (not starting with a digit), no trailing '/'"
            )
        for name in ("base_frame", "object_frame", "hand_frame"):
            v = getattr(self, name)
            if not _ROS_FRAME.fullmatch(v):
                raise ConfigError(
                    f"ros2.{name} {v!r} is invalid: use 1-200 letters, digits, '_', '/', '.', '-'"
                )


_ROS_NAMESPACE = re.compile(r"^(/[A-Za-z_][A-Za-z0-9_]{0,62})+$")
_ROS_FRAME = re.compile(r"^[A-Za-z0-9_./\-]{1,200}$")


@dataclass
class WorkcellConfig:
    """Where things are, in the robot base frame (x forward, z up), metres. The same on every
    robot, real or simulated: the table plane that drops table contacts comes from here."""

    table_center: list[float] = field(default_factory=lambda: [0.0, 0.0, -0.025])
    table_size: list[float] = field(default_factory=lambda: [1.5, 1.5, 0.05])
    # The object frame (origin at the object's bounding-box centre, z up) in the base frame.
    # The twins stand each placed object on the table at this x, y (z then follows from the
    # object's height); on a real robot all three come from here or from calibration.
    object_xyz: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    object_yaw_deg: float = 0.0

    @property
    def table_top_z(self) -> float:
        return float(self.table_center[2]) + float(self.table_size[2]) / 2

    def check(self) -> None:
        for name, n in (("table_center", 3), ("table_size", 3), ("object_xyz", 3)):
            v = getattr(self, name)
            if len(v) != n or not all(math.isfinite(x) for x in v):
                raise ConfigError(f"workcell.{name}: expected {n} finite numbers, got {v}")
        if not all(x > 0 for x in self.table_size):
            raise ConfigError(f"workcell.table_size must be positive, got {self.table_size}")
        if not math.isfinite(self.object_yaw_deg):
            raise ConfigError("workcell.object_yaw_deg must be finite")


def _default_device(kind: str) -> Any:
    return device_config(kind, {})


@dataclass
class Config:
    # Which named set of settings the others start from (PROFILES); `--profile` on the
    # commands that train, recognise, evaluate and serve.
    profile: Profile = "robust"
    recognition: RecognitionConfig = field(default_factory=RecognitionConfig)
    observation: ObservationConfig = field(default_factory=ObservationConfig)
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    grid: GridConfig = field(default_factory=GridConfig)
    session: SessionConfig = field(default_factory=SessionConfig)
    sim: SimConfig = field(default_factory=SimConfig)
    service: ServiceConfig = field(default_factory=ServiceConfig)
    workcell: WorkcellConfig = field(default_factory=WorkcellConfig)
    recording: RecordingConfig = field(default_factory=RecordingConfig)
    ros2: Ros2Config = field(default_factory=Ros2Config)
    # Devices: `type` picks the device type (activetouch.device_types), the rest its settings.
    hand: Any = field(default_factory=lambda: _default_device("hand"))
    arm: Any = field(default_factory=lambda: _default_device("arm"))


DEVICE_SECTIONS = ("hand", "arm")


def _apply(cfg: Config, data: dict[str, Any], prefix: str, devices: dict[str, dict]) -> None:
    """Like `apply_section` on the whole config, but the device sections are gathered raw
    into `devices` (their settings depend on their type, known only once all are read)."""
    rest = {}
    for k, v in data.items():
        if k in DEVICE_SECTIONS:
            if not isinstance(v, dict):
                raise ConfigError(f"{prefix}{k}: expected a table of settings")
            devices[k].update(v)
        else:
            rest[k] = v
    apply_section(cfg, rest, prefix)


def load_config(
    path: str | os.PathLike | None = None, overrides: list[str] | None = None
) -> Config:
    """Defaults, then the TOML file at `path`, then `section.key=value` overrides."""
    cfg = Config()
    devices: dict[str, dict] = {k: {} for k in DEVICE_SECTIONS}
    data: dict[str, Any] | None = None
    if path is not None:
        p = Path(path)
        try:
            data = tomllib.loads(p.read_text())
        except FileNotFoundError:
            raise ConfigError(f"{p}: no such config file") from None
        except tomllib.TOMLDecodeError as e:
            raise ConfigError(f"{p}: not valid TOML: {e}") from None
        except (OSError, UnicodeDecodeError) as e:
            raise ConfigError(f"{p}: cannot read the config file ({e})") from None
    apply_profile(cfg, chosen_profile(data, overrides or []), devices)
    if path is not None and data is not None:
        try:
            _apply(cfg, data, "", devices)
        except ConfigError as e:
            raise ConfigError(f"{p}: {e}") from None
    for item in overrides or []:
        if "=" not in item:
            raise ConfigError(f"override {item!r}: expected section.key=value")
        dotted, raw = item.split("=", 1)
        parts = dotted.strip().split(".")
        try:
            value: Any = tomllib.loads(f"v = {raw}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw  # a bare word is a string
        nested: dict[str, Any] = {parts[-1]: value}
        for part in reversed(parts[:-1]):
            nested = {part: nested}
        _apply(cfg, nested, "", devices)
    set_devices(cfg, devices)
    _check_choices(cfg)
    default_workcell(cfg)
    hand_defaults(cfg)
    cfg.workcell.check()
    cfg.recording.check()
    cfg.ros2.check()
    return cfg


def chosen_profile(data: dict[str, Any] | None, overrides: list[str]) -> str:
    """The profile the last ``profile=`` override names, else the file's, else the default."""
    name: Any = (data or {}).get("profile", Config.profile)
    for item in overrides:
        key, _, raw = item.partition("=")
        if key.strip() == "profile":
            name = raw.strip().strip("\"'")
    if name not in PROFILES:
        raise ConfigError(f"profile: {name!r} is not one of {', '.join(PROFILES)}")
    return str(name)


def apply_profile(cfg: Config, name: str, devices: dict[str, dict]) -> None:
    cfg.profile = name  # type: ignore[assignment]
    for dotted, value in PROFILES[name].items():
        nested: dict[str, Any] = {}
        node = nested
        parts = dotted.split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = value
        _apply(cfg, nested, "", devices)


def profile_settings(
    cfg: Config, model_config: dict[str, Any] | None = None, policy: str | None = None
) -> dict[str, Any]:
    """The settings that distinguish the recognition method, as `train` and `recognize`
    print them (and results store them) beside the profile's name. `model_config`: the
    model's saved configuration, whose training settings (the pooling cell the library chose,
    the grid) are the ones a recognition with it used; `policy`: the one this recognition
    plans with, where the request named one over `planner.policy`."""
    rc, obs = cfg.recognition, cfg.observation
    cell, margin = obs.translation_cell_m, cfg.grid.margin_m
    if model_config:
        cell = model_config.get("observation", {}).get("translation_cell_m", cell)
        margin = model_config.get("grid", {}).get("margin_m", margin)
    out: dict[str, Any] = {
        "recognition.belief": rc.belief,
        "observation.translation_cell_m": cell,
        "observation.cells_from": obs.cells_from,
        "grid.margin_m": margin,
        "planner.policy": policy or cfg.planner.policy,
    }
    if rc.belief == "pose":
        out["recognition.pose_range_m"] = rc.pose_range_m
        out["recognition.pose_range_deg"] = rc.pose_range_deg
        out["recognition.pose_floor"] = rc.pose_floor
        out["recognition.pose_on_table"] = rc.pose_on_table
        out["recognition.pose_contact_offset_m"] = rc.pose_contact_offset_m
        out["recognition.pose_contact_sigma_m"] = rc.pose_contact_sigma_m
        out["recognition.pose_follow"] = rc.pose_follow
        out["recognition.pose_alternate_share"] = rc.pose_alternate_share
        out["recognition.pose_drift_m"] = rc.pose_drift_m
        out["recognition.pose_grasps_weight"] = rc.pose_grasps_weight
        out["recognition.likelihood_floor"] = rc.likelihood_floor
        out["recognition.likelihood_pose_sigma_m"] = rc.likelihood_pose_sigma_m
    out["session.average_readings"] = cfg.session.average_readings
    out["hand.type"] = cfg.hand.type
    return out


def profile_line(cfg: Config, policy: str | None = None) -> str:
    """'NAME: key value, ...' for a terminal (`policy`: as `profile_settings`)."""
    items = ", ".join(f"{k} {v}" for k, v in profile_settings(cfg, policy=policy).items())
    return f"{cfg.profile}: {items}"


def default_workcell(cfg: Config) -> None:
    """An arm type that cannot work in the default workcell (a table at the base frame's origin,
    e.g. inside Baxter) gets its own when the configuration did not set one."""
    if cfg.workcell != WorkcellConfig():
        return
    values = cfg.arm.default_workcell()
    if values:
        cfg.workcell = WorkcellConfig(**values)
        log.info("arm.type=%s: using its default [workcell] %s", cfg.arm.type, values)


def hand_defaults(cfg: Config) -> None:
    """Another hand (the BH8) brings its own values of some `[grid]` and `[recognition]`
    settings (its size, its cells), used where the configuration left them at the defaults."""
    for section, values in (cfg.hand.default_settings() or {}).items():
        current = getattr(cfg, section)
        base = type(current)()
        for key, value in values.items():
            if getattr(current, key) == getattr(base, key):
                setattr(current, key, value)


def set_devices(cfg: Config, raw: dict[str, dict], only: tuple[str, ...] = DEVICE_SECTIONS) -> None:
    """Make the typed `cfg.hand` / `cfg.arm` from raw sections (``{"type": ..., ...}``)."""
    for kind in only:
        setattr(cfg, kind, device_config(kind, raw.get(kind, {})))


def _check_choices(obj: Any, prefix: str = "") -> None:
    """Every setting typed as a `Literal` holds one of its words (also those set in code)."""
    hints = typing.get_type_hints(type(obj))
    for f in dataclasses.fields(obj):
        value, tp = getattr(obj, f.name), hints.get(f.name)
        if dataclasses.is_dataclass(value):
            _check_choices(value, f"{prefix}{f.name}.")
        elif typing.get_origin(tp) is Literal and value not in typing.get_args(tp):
            allowed = ", ".join(typing.get_args(tp))
            raise ConfigError(f"{prefix}{f.name}: {value!r} is not one of {allowed}")


def as_dict(cfg: Any) -> dict[str, Any]:
    return dataclasses.asdict(cfg)
