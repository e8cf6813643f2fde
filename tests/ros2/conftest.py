"""Fixtures of the ROS 2 tests."""

from __future__ import annotations

from typing import Any

import pytest

from tests.ros2.hashes import file_defs, srv_defs

TRIGGER = "std_srvs/srv/Trigger"


@pytest.fixture(scope="module")
def store() -> Any:
    """rosbags' Jazzy store with Trigger and activetouch_interfaces, from the files."""
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    defs = srv_defs("std_srvs", "Trigger", "---\nbool success\nstring message\n")
    defs.update(file_defs())
    ts.register({k: v for k, v in defs.items() if k not in ts.fielddefs})
    return ts
