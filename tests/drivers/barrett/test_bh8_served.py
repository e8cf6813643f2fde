"""The BH8 driver served as `activetouch serve` serves it (make_devices, the device nodes and
their links) on its emulator over python-can's virtual bus, used through `RemoteHand` over
Zenoh on 127.0.0.1 (scouting off): 96 cells cross the wire."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from activetouch.config import load_config
from activetouch.daemon.device_nodes import DeviceNodes
from activetouch.daemon.remote import Latest, RemoteHand
from activetouch.daemon.supervision import LinkSettings
from activetouch.devices import make_devices
from activetouch.emulators.barrett_bh8 import BH8Emulator, BH8EmulatorConfig, FingerObject
from activetouch.errors import MessageError
from activetouch.transport.keys import Keys
from activetouch.transport.messages import HandInfo, HandStateMsg
from activetouch.transport.zenoh_session import ZenohSession

_n = itertools.count()
# Generous bounds: each is a deadline for something that happens far sooner on an idle
# machine (the HI and a close take well under a second on the emulator).
WAIT_S = 60.0


class Served:
    """The emulator, the devices of a barrett-bh8 config and their nodes, as the daemon makes
    them; `RemoteHand` the client. Everything started here is stopped on exit."""

    def __init__(self, node: ZenohSession, client: ZenohSession, obj: FingerObject) -> None:
        n = next(_n)
        self.robot = f"bh8served{n}"
        channel = f"bh8-served-{n}"
        self.emu = BH8Emulator(BH8EmulatorConfig(channel=channel, obj=obj))
        self.cfg = load_config(
            None,
            [
                "hand.type=barrett-bh8",
                "hand.can_interface=virtual",
                f"hand.can_channel={channel}",
                "hand.wake_settle_s=0.01",
                "hand.initialize_on_connect=true",
                # A loaded machine may leave the poll thread late; not a lost stream here.
                "hand.stream_timeout_s=1.0",
                "arm.type=fake",
            ],
        )
        self.node, self.client = node, client
        self.devices = self.nodes = None
        self.hand: RemoteHand | None = None

    def __enter__(self) -> Served:
        self.emu.start()
        try:
            self.devices = make_devices(self.cfg, None, connect=False)
            self.nodes = DeviceNodes(
                self.devices,
                self.node.session,
                self.robot,
                state_hz=20.0,
                links=LinkSettings(retry_s=0.05, check_s=0.2, lost_after_s=WAIT_S),
            )
            self.hand = RemoteHand(self.client.session, self.robot, timeout=10.0)
            self.hand.wait_alive(WAIT_S)  # the token: once the link connected the hand (HI)
            self.hand.connect()
        except BaseException:
            self.__exit__()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        if self.hand is not None:
            self.hand.close()
        if self.nodes is not None:
            self.nodes.close()
        if self.devices is not None:
            self.devices.close()
        self.emu.stop()


@pytest.fixture
def served(node_session: ZenohSession, client_session: ZenohSession):
    obj = FingerObject(contact_angle=[0.6, 0.9, 0.7])  # every pad presses cells 10, 13, 16
    with Served(node_session, client_session, obj) as s:
        yield s


def test_the_bh8_is_served_with_its_96_cells(served: Served, client_session) -> None:
    hand = served.hand
    assert hand is not None
    assert hand.info() == HandInfo(n_sensors=96, device="barrett-bh8")
    assert hand.n_sensors == 96
    assert served.emu.counts["hi"] == 4  # hand.initialize_on_connect: initialised on connect

    st = hand.state()
    assert st.pressures.shape == (96,) and st.contact.shape == (96,)
    assert not st.stale and not st.contact.any()  # open, nothing touching
    published = client_session.closing(
        Latest(client_session.session, Keys(served.robot).hand_state, HandStateMsg)
    )
    msg = published.wait(timeout=WAIT_S)
    assert len(msg.pressures) == len(msg.contact) == 96 and published.invalid == 0

    # 96 thresholds and a mask of cells beyond the ReFlex's 38 are taken and applied by the
    # driver (no finger stops on a masked cell, no grasp reports it); other counts are refused.
    assert hand.set_contact_thresholds([0.5] * 96) is True
    assert hand.mask_sensors([40, 95]) is True
    with pytest.raises(MessageError, match=r"38 values, expected 96.*barrett-bh8, 96 sensors"):
        hand.set_contact_thresholds([0.5] * 38)
    with pytest.raises(MessageError, match=r"sensor_ids\[0\]`: Expected `int` <= 95"):
        hand.mask_sensors([96])

    grasp = hand.guarded_close()
    ids = grasp.sensor_ids.tolist()
    # F1's pad (0..23), F2's (24..47), F3's (48..71): cells 10, 13, 16 of each, 40 masked.
    assert ids == [10, 13, 16, 34, 37, 58, 61, 64]
    assert grasp.xyz.shape == (8, 3) and np.all(np.isfinite(grasp.xyz))
    assert np.all(grasp.pressures > 0)
    after = hand.state()
    assert set(np.flatnonzero(after.contact).tolist()) >= set(ids)
    hand.open()
    assert not hand.state().contact.any()
