"""Faulty sensors over a twin hand (`activetouch.recognition.faults`), for either hand."""

from __future__ import annotations

import numpy as np

from activetouch.interfaces import Grasp
from activetouch.recognition.faults import (
    SPURIOUS_FACTOR,
    SensorFaults,
    draw_faulty_sensors,
    fault_rng,
    faulty_reading,
    spurious_contacts,
)
from activetouch.sim.world import HandContacts


class FaultyReadings:
    """Faulty sensors (`activetouch.recognition.faults`) over a twin hand (mixed in before
    `SimHand` or `SimBH8Hand`): noise, dead and stuck sensors act on every reading, so the
    guarded close reacts to them as the real hand would; spurious contacts are added to the
    reported grasp only; sensor drift offsets every reading by its rate times the grasps done;
    a finger offset moves the reported angles and the contacts with them (the sites where the
    finger would be at the angle it reports). The extra noise and drift are in the ReFlex's
    units, scaled for another hand by the ratio of the contact thresholds (`noise_scale`)."""

    faults: SensorFaults
    noise_scale: float = 1.0

    def reseed(self, seed: int) -> None:
        super().reseed(seed)  # type: ignore[misc]
        self.faulty = draw_faulty_sensors(self.faults, self.seed, self.n_sensors)  # type: ignore[attr-defined]
        self._fault_rng = fault_rng(self.seed)  # type: ignore[attr-defined]
        self._grasps_done = 0

    def _sense(self, contacts: HandContacts, rng: np.random.Generator):  # type: ignore[no-untyped-def]
        pressures, depth = super()._sense(contacts, rng)  # type: ignore[misc]
        return (
            faulty_reading(
                pressures,
                self.faults,
                self.faulty,
                self._fault_threshold(),
                self._fault_rng,
                self.noise_scale,
                self._grasps_done,
            ),
            depth,
        )

    def _fault_threshold(self) -> float:
        return float(self.cfg.contact_threshold)  # type: ignore[attr-defined]

    def guarded_close(self) -> Grasp:
        grasp = super().guarded_close()  # type: ignore[misc]
        self._grasps_done += 1
        grasp = self._offset_fingers(grasp)
        in_contact = np.zeros(self.n_sensors, dtype=bool)  # type: ignore[attr-defined]
        in_contact[grasp.sensor_ids] = True
        extra = spurious_contacts(in_contact, self.faults, self.faulty, self._fault_rng)
        extra = extra[~self.masked[extra]]  # type: ignore[attr-defined]
        if extra.size == 0:
            return grasp
        ids = np.concatenate([grasp.sensor_ids, extra])
        order = np.argsort(ids, kind="stable")  # sensor ids ascending, as the twin reports
        pressure = np.full(extra.size, SPURIOUS_FACTOR * self._fault_threshold())
        sites = self.world.sensor_sites_hand(grasp.finger_angles)  # type: ignore[attr-defined]
        return Grasp(
            sensor_ids=ids[order],
            xyz=np.concatenate([grasp.xyz, sites[extra]])[order],
            pressures=np.concatenate([grasp.pressures, pressure])[order],
            finger_angles=grasp.finger_angles,
            preshape=grasp.preshape,
        )

    def sensor_sites(self) -> np.ndarray:
        """Where the hand believes its sensors are: at the finger angles it reports, which the
        run's finger offsets put off the true ones."""
        w = self.world  # type: ignore[attr-defined]
        return w.sensor_sites_hand(
            np.asarray(w.proximal, dtype=np.float64) + self.faulty.finger_offset
        )

    def _offset_fingers(self, grasp: Grasp) -> Grasp:
        """`grasp` as a hand whose finger angles read off by the run's offsets reports it."""
        off = self.faulty.finger_offset
        if not off.any():
            return grasp
        angles = np.asarray(grasp.finger_angles, dtype=np.float64) + off
        sites = self.world.sensor_sites_hand(angles)  # type: ignore[attr-defined]
        return Grasp(
            sensor_ids=grasp.sensor_ids,
            xyz=sites[grasp.sensor_ids].reshape(-1, 3),
            pressures=grasp.pressures,
            finger_angles=angles,
            preshape=grasp.preshape,
        )
