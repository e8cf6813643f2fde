"""activetouch/transport/rmw_zenoh.py against byte vectors and keys written out by hand from
rmw_zenoh's format, and the [ros2] settings' errors."""

from __future__ import annotations

import pytest

from activetouch.config import load_config
from activetouch.errors import ConfigError, MessageError
from activetouch.transport import rmw_zenoh as rz

GID = bytes(range(0x10, 0x20))
# seq 5, stamp 0x0102030405060708, GID length 16, GID: 33 bytes, little endian.
GID_VECTOR = b"\x05\x00\x00\x00\x00\x00\x00\x00\x08\x07\x06\x05\x04\x03\x02\x01\x10" + GID
LEGACY_VECTOR = (
    b"\x0fsequence_number" + b"\x05\x00\x00\x00\x00\x00\x00\x00"
    b"\x10source_timestamp" + b"\x08\x07\x06\x05\x04\x03\x02\x01"
    b"\x0asource_gid" + b"\x10" + GID
)


def test_gid_attachment_bytes() -> None:
    att = rz.Attachment(5, 0x0102030405060708, GID)
    assert att.encode("gid") == GID_VECTOR and len(GID_VECTOR) == 33
    assert rz.decode_attachment(GID_VECTOR) == (att, "gid")


def test_legacy_attachment_bytes() -> None:
    att = rz.Attachment(5, 0x0102030405060708, GID)
    assert att.encode("legacy") == LEGACY_VECTOR
    assert rz.decode_attachment(LEGACY_VECTOR) == (att, "legacy")
    with pytest.raises(MessageError, match="expected gid"):
        rz.decode_attachment(LEGACY_VECTOR, "gid")


@pytest.mark.parametrize("data", [b"", bytes(32), GID_VECTOR[:16] + b"\x08" + GID[:8]])
def test_malformed_attachments_are_refused(data: bytes) -> None:
    with pytest.raises(MessageError, match="attachment"):
        rz.decode_attachment(data)


def test_keys_and_tokens() -> None:
    h = "RIHS01_" + "ab" * 32
    assert rz.dds_type("std_srvs/srv/Trigger") == "std_srvs::srv::dds_::Trigger_"
    assert rz.data_key(0, "/activetouch/estop", "std_srvs/srv/Trigger", h) == (
        f"0/activetouch/estop/std_srvs::srv::dds_::Trigger_/{h}"
    )
    assert rz.qos_key(depth=10) == "::,10:,:,:,,"
    assert rz.qos_key(depth=42) == "::,:,:,:,,"
    node = rz.NodeInfo(domain_id=3, zid="aa11", node_id=0, name="activetouch")
    assert node.node_token() == "@ros2_lv/3/aa11/0/0/NN/%/%/activetouch"
    assert node.resolve("~/status") == "/activetouch/status"
    assert node.resolve("joint_states") == "/joint_states"
    assert node.entity_token(4, rz.SERVICE, "/activetouch/status", "std_srvs/srv/Trigger", h,
                             "::,10:,:,:,,") == (
        f"@ros2_lv/3/aa11/0/4/SS/%/%/activetouch/%activetouch%status/"
        f"std_srvs::srv::dds_::Trigger_/{h}/::,10:,:,:,,"
    )  # fmt: skip
    lab = rz.NodeInfo(domain_id=0, zid="aa11", node_id=0, name="activetouch", namespace="/lab/a")
    assert lab.fqn == "/lab/a/activetouch"
    assert lab.resolve("joint_states") == "/lab/a/joint_states" and lab.resolve("/tf") == "/tf"
    assert lab.node_token() == "@ros2_lv/0/aa11/0/0/NN/%/%lab%a/activetouch"
    assert len(rz.gid_of(lab.node_token())) == 16


def test_cdr_has_the_encapsulation_header() -> None:
    t = rz.Ros2Types()
    data = t.serialize(t.new("std_srvs/srv/Trigger_Response", success=True, message="hi"),
                       "std_srvs/srv/Trigger_Response")  # fmt: skip
    assert data == b"\x00\x01\x00\x00" + b"\x01\x00\x00\x00" + b"\x03\x00\x00\x00hi\x00"
    assert t.serialize(t.new("std_srvs/srv/Trigger_Request",
                             structure_needs_at_least_one_member=0),
                       "std_srvs/srv/Trigger_Request") == b"\x00\x01\x00\x00\x00"  # fmt: skip
    with pytest.raises(MessageError, match="CDR"):
        t.deserialize(b"\x07", "std_srvs/srv/Trigger_Response")


@pytest.mark.parametrize(
    ("override", "match"),
    [
        ("ros2.attachment=v2", "ros2.attachment: 'v2' is not one of gid, legacy"),
        ("ros2.domain_id=233", "ros2.domain_id must be 0-232"),
        ("ros2.namespace=lab", "ros2.namespace 'lab' is invalid"),
        ("ros2.namespace=/lab/", "ros2.namespace '/lab/' is invalid"),
        ("ros2.hand_frame=a b", "ros2.hand_frame 'a b' is invalid"),
        ("ros2.enabled=sometimes", "ros2.enabled: expected true/false"),
        ("ros2.domain=1", "unknown setting 'ros2.domain'"),
    ],
)
def test_bad_ros2_settings_name_the_key(override: str, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        load_config(None, [override])


def test_ros2_is_off_by_default() -> None:
    cfg = load_config(None)
    assert cfg.ros2.enabled is False and cfg.ros2.attachment == "gid"
    assert cfg.ros2.domain_id == 0 and cfg.ros2.namespace == ""


def test_the_face_needs_the_daemon_role(tmp_path) -> None:
    from activetouch.daemon.process import DaemonOptions

    cfg = load_config(None, ["ros2.enabled=true", "hand.type=fake", "arm.type=fake"])
    with pytest.raises(ConfigError, match=r"ros2\.enabled: .*--role all or --role daemon"):
        DaemonOptions(mode="sim", role="nodes", data=tmp_path, model_dir=tmp_path, cfg=cfg)
    DaemonOptions(mode="sim", role="daemon", data=tmp_path, model_dir=tmp_path, cfg=cfg)
