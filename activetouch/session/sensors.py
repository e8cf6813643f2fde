"""Which of the hand's sensors count in one recognition, and what counts as their contact.

The session (`session/loop.py`) owns one `RecognitionSensors` per recognition: at the start it
reads the open hand and masks the sensors that lie (the tactile calibration's flags, stuck,
dead) and sets contact thresholds from the measured noise; before each later grasp it may
re-zero (`session.rezero_readings`); after each close it decides the contacts again (the mean
of `session.average_readings` readings, or `session.confirm_readings` that must all agree),
and drops the masked sensors and the contacts under their thresholds. The arithmetic is in
`session/contacts.py`; this class keeps the state between grasps and reads the hand.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable

import numpy as np

from activetouch.calibration.tactile import read_states
from activetouch.config import SessionConfig
from activetouch.interfaces import Grasp, Hand
from activetouch.session.contacts import (
    RestLevels,
    above_thresholds,
    confirmed,
    mask_reasons,
    mean_contacts,
    mean_thresholds,
    noise_thresholds,
    rest_levels,
    without_sensors,
    zero_walk,
)

log = logging.getLogger(__name__)

# Reads `n` hand states, waiting for them (and counting the robot time they took).
ReadWaiting = Callable[[int], tuple[np.ndarray, np.ndarray]]


class RecognitionSensors:
    """The masks and contact thresholds of one recognition, grasp by grasp."""

    def __init__(self, hand: Hand, cfg: SessionConfig, read_waiting: ReadWaiting) -> None:
        self.hand, self.cfg, self._read_waiting = hand, cfg, read_waiting
        self.masked = np.zeros(0, dtype=np.int64)
        self.thresholds: np.ndarray | None = None
        # With `session.average_readings` engaged: the rest levels and the hand's own
        # thresholds, from which the mean of the readings after each close is judged.
        self.averaging: tuple[RestLevels, np.ndarray] | None = None
        # The rest levels read at the start, the contact thresholds then in force (the hand's
        # own where higher) and the hand's own: re-zeroing shifts the last two by each
        # sensor's walk since (`rezero`).
        self._rest0: tuple[RestLevels, np.ndarray, np.ndarray | None] | None = None

    def mask_at_rest(self) -> dict[int, str]:
        """With the hand open, away from the object: read its sensors at rest, and for this
        recognition ignore those its tactile calibration flagged, those in contact in most
        readings (stuck) and those that read nothing (dead): by the hand where it can, so no
        finger stops on them, and here in any case; and count a contact only above the
        sensor's rest level plus `session.noise_k` sigma. Sensor id -> why it is ignored."""
        # `session.rest_readings` distinct states; a stalled stream (2 s) is the grasp's error.
        rest = rest_levels(*read_states(self.hand, self.cfg.rest_readings, timeout_s=2.0))
        why = mask_reasons(self.hand.sensor_flags(), rest, len(rest.mean))
        self.masked = np.array(sorted(why), dtype=np.int64)
        self.hand.mask_sensors(self.masked.tolist())  # [] too: clears an earlier recognition's
        self.thresholds, self.averaging, self._rest0 = None, None, None
        if rest.readings > 1:
            thr = noise_thresholds(rest, self.cfg.noise_k)
            self.hand.set_contact_thresholds(thr.tolist())
            self.thresholds = thr
            self.averaging = self._averaging_levels(rest, thr)
            own = self.hand.own_contact_thresholds()
            own = None if own is None else np.asarray(own, dtype=np.float64)
            self._rest0 = (rest, thr if own is None else np.maximum(thr, own), own)
        if why:
            log.warning(
                "sensors ignored for this recognition: %s",
                "; ".join(f"{i} {w}" for i, w in why.items()),
            )
        return why

    def rezero(self, grasp_number: int) -> dict[int, str]:
        """Before grasp `grasp_number` (the hand open since the last close): read it
        `session.rezero_readings` times; ignore from now on the sensors in contact in most
        readings (a zero that drifted up, a sensor stuck since the start), and move every
        other sensor's contact threshold by the walk of its rest level since the start (the
        readings' mean against the start's). The sensors newly ignored -> why."""
        n = self.cfg.rezero_readings
        if n < 1 or self._rest0 is None:
            return {}
        pressures, contact = self._read_waiting(n)
        if not len(pressures):
            return {}
        touched = np.flatnonzero(contact.mean(axis=0) > 0.5)
        new = np.setdiff1d(touched, self.masked)
        why = f"in contact with the hand open before grasp {grasp_number}"
        if new.size:
            self.masked = np.union1d(self.masked, new).astype(np.int64)
            self.hand.mask_sensors(self.masked.tolist())
            log.warning("sensors ignored from now on: %s (%s)", new.tolist(), why)
        rest0, thr0, own0 = self._rest0
        # The thresholds in force move with each zero, so a contact needs the same press as then.
        shift = zero_walk(rest0, pressures, touched)
        thr = thr0 + shift
        self.hand.set_contact_thresholds(thr.tolist())
        self.thresholds = thr
        if self.averaging is not None and own0 is not None:
            rest = dataclasses.replace(rest0, mean=rest0.mean + shift)
            self.averaging = (rest, own0 + shift)
        return {int(i): why for i in new}

    def _averaging_levels(
        self, rest: RestLevels, noise: np.ndarray
    ) -> tuple[RestLevels, np.ndarray] | None:
        """`rest` and the hand's own thresholds, where the noise thresholds at rest (`noise`)
        lift the median sensor over the hand's own: the close's reading then misses light
        contacts, and the session judges the mean of `session.average_readings` readings.
        None: off, a quiet hand (its close reads as in training), or a hand that does not tell
        its own thresholds or its sensors' sites."""
        n = self.cfg.average_readings
        if n < 1:
            return None
        own = self.hand.own_contact_thresholds()
        if own is None or self.hand.sensor_sites() is None:
            log.warning(
                "session.average_readings=%d: this hand does not tell its own contact "
                "thresholds or its sensors' sites; contacts are decided on the close's reading",
                n,
            )
            return None
        own = np.asarray(own, dtype=np.float64)
        if np.median(noise) <= np.median(own):
            return None
        return rest, own

    def after_close(self, grasp: Grasp) -> Grasp:
        """The close's contacts decided again while the fingers still hold the object: on the
        mean of new readings (`averaged`), or kept only where `session.confirm_readings`
        readings all agree; else `grasp` as it is."""
        if self.averaging is not None:
            return self.averaged(grasp)
        if self.cfg.confirm_readings > 0 and len(grasp.sensor_ids):
            states = self._read_waiting(self.cfg.confirm_readings)
            return confirmed(grasp, *states, self.thresholds)
        return grasp

    def averaged(self, grasp: Grasp) -> Grasp:
        """The close's contacts decided again on the mean of new readings of the closed hand
        (`mean_contacts`), the sensors placed where the hand says they are. A hand that gives
        fewer readings within 2 s is judged on those (its thresholds for that many); none:
        the close's grasp as it is."""
        assert self.averaging is not None
        rest, own = self.averaging
        n = self.cfg.average_readings
        pressures, _ = self._read_waiting(n)
        sites = self.hand.sensor_sites()
        if len(pressures) < n:
            log.warning("the hand gave %d of %d readings after the close", len(pressures), n)
        if not len(pressures) or sites is None:
            return grasp
        thr = mean_thresholds(rest, self.cfg.noise_k, len(pressures), own)
        return mean_contacts(grasp, pressures, thr, np.asarray(sites))

    def counted(self, grasp: Grasp) -> Grasp:
        """`grasp` without the masked sensors' contacts and, unless its contacts were decided
        on the mean (which has its own thresholds), those under their noise thresholds."""
        if self.masked.size:
            grasp = without_sensors(grasp, self.masked)
        if self.thresholds is not None and self.averaging is None:
            grasp = above_thresholds(grasp, self.thresholds)
        return grasp
