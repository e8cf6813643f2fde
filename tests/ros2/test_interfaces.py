"""The interface package ros2/activetouch_interfaces/: its files parse with rosbags, their RIHS01
hashes (computed here from the files) are the ones the daemon's face announces, the face's
copies of the definitions are the files, and the colcon files list every interface."""

from __future__ import annotations

import re

import pytest

from activetouch.transport.rmw_zenoh import Ros2Types
from activetouch.transport.ros2_interfaces import DEFINITIONS, definitions
from tests.ros2.client import TRIGGER_HASH
from tests.ros2.hashes import PACKAGE_DIR, file_defs, rihs01

INTERFACES = [
    "activetouch_interfaces/msg/Progress",
    "activetouch_interfaces/msg/RecognitionResult",
    "activetouch_interfaces/msg/Tactile",
    "activetouch_interfaces/srv/Recognize",
]


def test_the_files_parse_and_define_every_interface() -> None:
    defs = file_defs()
    for name in INTERFACES:
        if "/srv/" in name:
            assert f"{name}_Request" in defs and f"{name}_Response" in defs
        else:
            assert name in defs
    fields = dict(defs["activetouch_interfaces/msg/Tactile"][1])
    assert fields["pressures"][1][1] == 38 and fields["contact"][1][1] == 38


def test_std_srvs_trigger_hash_is_the_published_one() -> None:
    # Trigger_Request / _Response / _Event / the service: values published upstream.
    assert rihs01("std_srvs/srv/Trigger_Request") == (
        "RIHS01_d010825374ce8918e72bfd826c82603e60f45419e932ea976f807b74a863a199"
    )
    assert rihs01("std_srvs/srv/Trigger_Response") == (
        "RIHS01_2d946c21e2fc3f1e9ca6986a8191d85fcc70097a8bb7771a053564bc47009cdf"
    )
    assert rihs01("std_srvs/srv/Trigger_Event") == (
        "RIHS01_ec4a1d26b0575e61906890342aba9523a2360e9845857c5590fa6e23bc39e1c2"
    )
    assert rihs01("std_srvs/srv/Trigger") == TRIGGER_HASH
    assert Ros2Types().hash("std_srvs/srv/Trigger") == TRIGGER_HASH


@pytest.mark.parametrize("name", INTERFACES)
def test_the_face_announces_the_hashes_of_the_files(name: str) -> None:
    h = rihs01(name)
    assert re.fullmatch(r"RIHS01_[0-9a-f]{64}", h)
    assert Ros2Types(definitions()).hash(name) == h


def test_the_faces_definitions_are_the_files() -> None:
    assert sorted(DEFINITIONS) == INTERFACES
    for text, rel in DEFINITIONS.values():
        assert (PACKAGE_DIR / rel).read_text() == text, rel


def test_the_colcon_files_name_every_interface() -> None:
    cmake = (PACKAGE_DIR / "CMakeLists.txt").read_text()
    xml = (PACKAGE_DIR / "package.xml").read_text()
    assert "rosidl_generate_interfaces" in cmake
    for _, rel in DEFINITIONS.values():
        assert f'"{rel}"' in cmake
    assert "<name>activetouch_interfaces</name>" in xml
    assert "<member_of_group>rosidl_interface_packages</member_of_group>" in xml
    for dep in ("std_msgs", "geometry_msgs"):
        assert f"<depend>{dep}</depend>" in xml and dep in cmake
