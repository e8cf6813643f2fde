"""One recognition in the twin: place the object, build the policy, run the session.

Used by `activetouch recognize`, `eval`, `demo` and the daemon's simulated robot."""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from activetouch import paths
from activetouch.config import Config, SessionConfig, profile_settings
from activetouch.device_types import DEFAULT_ARM as FLOATING_ARM
from activetouch.devices import make_devices
from activetouch.errors import ConfigError, DataError
from activetouch.model import TrainedModel, load_model
from activetouch.objects.library import ObjectLibrary
from activetouch.planning.policies import POLICY_NAMES, Policy
from activetouch.recordings.format import placement_pose
from activetouch.session.loop import (
    Progress,
    RecognitionResult,
    RecognitionSession,
    policy_for,
)

if TYPE_CHECKING:
    from activetouch.devices import Devices
    from activetouch.planning.motion.base import Placement
    from activetouch.recordings.writer import SafeRecorder


def model_path(root: Path, explicit: str | None, hand_family: str = "reflex") -> Path:
    return Path(explicit) if explicit else paths.default_model(root, hand_family)


def load_trained(path: Path) -> TrainedModel:
    if not (path / "model.json").is_file():
        raise DataError(f"no model at {path}: train one first with `activetouch train`")
    return load_model(path)


def check_request(policy: str, max_moves: int, seed: int = 0) -> None:
    if seed < 0:
        raise ConfigError(f"the seed must be >= 0, got {seed}")
    if policy not in POLICY_NAMES:
        raise ConfigError(f"unknown policy {policy!r}; choose from {', '.join(POLICY_NAMES)}")
    if max_moves < 1:
        raise ConfigError(f"the move budget must be at least 1, got {max_moves}")


def stamped(
    res: RecognitionResult,
    cfg: Config,
    model: TrainedModel | None = None,
    policy: str | None = None,
) -> RecognitionResult:
    """`res` with the profile and method settings it ran with (`model`'s training ones, the
    `policy` it planned with)."""
    res.profile = cfg.profile
    res.settings = profile_settings(cfg, model.config if model is not None else None, policy)
    return res


def recognize_in_twin(
    model: TrainedModel,
    library: ObjectLibrary,
    object_name: str,
    policy_name: str,
    seed: int,
    cfg: Config,
    max_moves: int | None = None,
    on_progress: Callable[[Progress], None] | None = None,
    cancel: threading.Event | None = None,
    recorder: SafeRecorder | None = None,
) -> RecognitionResult:
    """Recognise `object_name` placed in a fresh twin; deterministic for a seed.

    The floating twin (``arm.type = "twin-floating"``, the default) is opened directly; any
    other arm (``twin-baxter``) runs on the configured devices (`make_devices`), which place
    the object as ``sim/place`` does. `data` is the data directory those devices read the
    object library from (default: the library's). `recorder`: the recording it writes
    (`recordings.writer.open_recorder`; the caller finishes it)."""
    # deferred: loads pybullet
    from activetouch.sim.twin import open_twin

    session_cfg = cfg.session
    if max_moves is not None:
        session_cfg = type(cfg.session)(**{**vars(cfg.session), "max_moves": int(max_moves)})
    check_request(policy_name, session_cfg.max_moves, seed)
    spec = library.get(object_name)
    policy = policy_for(model, policy_name, cfg.planner, cfg.recognition)
    rng = np.random.default_rng(seed)
    if cfg.arm.type != FLOATING_ARM:
        return _recognize_on_devices(
            model,
            library,
            spec.name,
            policy,
            rng,
            seed,
            cfg,
            session_cfg,
            on_progress,
            cancel,
            recorder,
            policy_name,
        )
    with open_twin(spec, cfg.sim, seed=seed, workcell=cfg.workcell, hand=cfg.hand) as twin:
        if recorder is not None:
            pl = twin.wrist.placement
            recorder.placement(placement_pose(pl.xyz, pl.yaw_rad))
        session = RecognitionSession(
            twin.hand,
            twin.wrist,
            model,
            policy,
            session_cfg,
            rng,
            on_progress,
            cancel,
            support_z=twin.support_z,
            recognition=cfg.recognition,
            recorder=recorder,
            library=library,
        )
        return stamped(session.run(), cfg, model, policy_name)


def _recognize_on_devices(
    model: TrainedModel,
    library: ObjectLibrary,
    object_name: str,
    policy: Policy,
    rng: np.random.Generator,
    seed: int,
    cfg: Config,
    session_cfg: SessionConfig,
    on_progress: Callable[[Progress], None] | None,
    cancel: threading.Event | None,
    recorder: SafeRecorder | None = None,
    policy_name: str | None = None,
) -> RecognitionResult:
    """The recognition on `make_devices(cfg)`: placed through the devices' ``sim/place``, the
    wrist told where the object stands, the table plane from the workcell (as the daemon
    does it)."""
    # The library's root is <data>/objects: the devices find the same objects there.
    with placed_devices(cfg, library.root.parent, object_name, seed, "recognize") as (
        devices,
        placement,
    ):
        if recorder is not None:
            recorder.placement(placement_pose(placement.xyz, placement.yaw_rad))
        session = RecognitionSession(
            devices.hand,
            devices.wrist,
            model,
            policy,
            session_cfg,
            rng,
            on_progress,
            cancel,
            support_z=placement.support_z(cfg.workcell.table_top_z),
            recognition=cfg.recognition,
            recorder=recorder,
            library=library,
        )
        return stamped(session.run(), cfg, model, policy_name)


@contextlib.contextmanager
def placed_devices(
    cfg: Config, data: Path, object_name: str, seed: int, what: str
) -> Iterator[tuple[Devices, Placement]]:
    """`make_devices(cfg, data)` with `object_name` placed through their ``sim/place`` and the
    wrist told where it stands; closed on exit. ConfigError for devices that cannot place
    (real ones): `what` names the command for the message."""

    devices = make_devices(cfg, data)
    try:
        if not devices.simulated or devices.ctx.place is None:
            raise ConfigError(
                f"hand.type={cfg.hand.type!r} with arm.type={cfg.arm.type!r} cannot place "
                f"{object_name!r}: {what} in-process needs simulated devices (twin, fake); "
                "for a real robot run `activetouch serve --hardware` and `recognize --connect`"
            )
        devices.ctx.place(object_name, seed)
        placement = devices.placement()
        devices.wrist.set_placement(placement)
        yield devices, placement
    finally:
        devices.close()


def result_record(res: RecognitionResult) -> dict:
    """What a recording's result message holds for an in-process recognition (the daemon's
    `RecognizeResult` field names)."""
    return {
        "label": res.label,
        "probability": float(res.probability),
        "labels": list(res.labels),
        "moves": res.moves,
        "skipped": res.skipped,
        "stop_reason": res.stop_reason,
        "pose_ids": [int(p) for p in res.pose_ids],
        "motion_s": res.motion_s,
        "motion_planning_s": res.motion_planning_s,
        "grasp_s": res.grasp_s,
        "search_s": res.search_s,
        "planning_s": res.planning_s,
        "total_s": res.total_s,
        "elapsed_s": res.elapsed_s,
    }
