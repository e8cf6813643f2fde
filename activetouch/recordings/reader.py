"""Reading a recording back: every message decoded, also from a file a crash cut short.

The file is read front to back (`mcap.stream_reader.StreamReader`), so a recording without
its summary and footer (the writer died) gives every chunk written before that: `complete`
says whether the footer was there.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.exceptions import McapError
from mcap.records import Channel, Footer, Message, Schema
from mcap.stream_reader import StreamReader

from activetouch.errors import DataError
from activetouch.recordings import format as fmt


@dataclass
class ChannelInfo:
    topic: str
    schema_name: str
    schema_encoding: str
    message_encoding: str
    count: int = 0


@dataclass
class Recording:
    path: Path
    complete: bool  # the footer was there (the writer finished)
    channels: dict[str, ChannelInfo] = field(default_factory=dict)
    json: dict[str, list[dict[str, Any]]] = field(default_factory=dict)  # topic -> payloads
    ros: dict[str, list[bytes]] = field(default_factory=dict)  # topic -> CDR payloads
    log_times: dict[str, list[int]] = field(default_factory=dict)

    @property
    def request(self) -> dict[str, Any]:
        return (self.json.get(fmt.REQUEST) or [{}])[0]

    @property
    def kind(self) -> str:
        """`fmt.RECOGNITION` or `fmt.CALIBRATION` (files before the field: recognitions)."""
        return str(self.request.get("kind", fmt.RECOGNITION))

    @property
    def result(self) -> dict[str, Any] | None:
        got = self.json.get(fmt.RESULT)
        return got[-1] if got else None

    @property
    def grasps(self) -> list[dict[str, Any]]:
        return self.json.get(fmt.GRASP, [])

    @property
    def beliefs(self) -> list[dict[str, Any]]:
        return self.json.get(fmt.BELIEF, [])

    @property
    def labels(self) -> list[str]:
        return [b["label"] for b in self.beliefs]

    def decoded(self, topic: str) -> list[Any]:
        """The ROS 2 messages of `topic`, deserialised with rosbags."""
        typename = self.channels[topic].schema_name
        return [fmt.deserialize(b, typename) for b in self.ros.get(topic, [])]


def read_recording(path: str | Path) -> Recording:
    p = Path(path)
    if not p.is_file():
        raise DataError(f"no recording at {p}")
    rec = Recording(path=p, complete=False)
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    with open(p, "rb") as f:
        try:
            for r in StreamReader(f, skip_magic=False).records:
                if isinstance(r, Schema):
                    schemas[r.id] = r
                elif isinstance(r, Channel):
                    channels[r.id] = r
                    s = schemas.get(r.schema_id)
                    rec.channels.setdefault(
                        r.topic,
                        ChannelInfo(
                            r.topic,
                            s.name if s else "",
                            s.encoding if s else "",
                            r.message_encoding,
                        ),
                    )
                elif isinstance(r, Message):
                    ch = channels.get(r.channel_id)
                    if ch is None:
                        continue
                    rec.channels[ch.topic].count += 1
                    rec.log_times.setdefault(ch.topic, []).append(r.log_time)
                    if ch.message_encoding == "json":
                        rec.json.setdefault(ch.topic, []).append(json.loads(r.data))
                    else:
                        rec.ros.setdefault(ch.topic, []).append(bytes(r.data))
                elif isinstance(r, Footer):
                    rec.complete = True
        except (McapError, EOFError, struct.error, ValueError) as e:
            if not rec.channels:  # nothing readable at all
                raise DataError(f"{p} is not a readable MCAP recording: {e}") from None
        except Exception as e:  # a torn chunk (zstd) or record: keep what came before
            if not rec.channels:
                raise DataError(f"{p} is not a readable MCAP recording: {e}") from None
    if fmt.REQUEST not in rec.json:
        raise DataError(f"{p} is not an activetouch recording (no {fmt.REQUEST} message)")
    return rec
