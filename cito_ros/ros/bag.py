"""rosbag2-compatible MCAP recording, without rosbag2.

A `BagWriter` writes one bag: a folder holding `<name>_0.mcap` (profile ros2,
schemas in `ros2msg` with their dependencies, each channel carrying its
offered QoS as rosbag2's MCAP plugin does, messages in CDR) and a rosbag2
`metadata.yaml` (version 9, storage mcap) as `ros2 bag` tools expect.
Messages come as CDR bytes or as message objects, which are serialized by
rclpy's typesupport (C) but for the types with sequences of numbers wider than
a byte (`exact_encoding_needed`), which mcap_ros2's encoder writes: for those
Jazzy's typesupport can append stray bytes that strict readers refuse. The bag is written in a
`.partial` folder and renamed into place only when it is complete and synced,
so a finished bag is never touched again and a crash leaves no half-written
bag under the final name.

Message definitions are read from the `.msg` files installed by the interface
packages (`<prefix>/share/<package>/msg/`), for any prefix on
AMENT_PREFIX_PATH and the interpreter's own prefix.
"""
from __future__ import annotations

import json
import os
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer as McapWriter
from mcap_ros2._dynamic import serialize_dynamic
from rclpy.serialization import serialize_message

PRIMITIVES = {"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32",
              "uint32", "int64", "uint64", "string", "wstring"}
SEPARATOR = "=" * 80
INFINITE_S, INFINITE_NS = 9223372036, 854775807
# rclpy's serialize_message in Jazzy overestimates the serialized size of a message with an empty sequence of
# numbers wider than a byte (measured: +8 bytes for a JointState with empty velocities, +8 per point of a
# JointTrajectory, whose accelerations are empty, +4 for an empty Float64MultiArray) and returns that many
# stray bytes at the end, which rosbags refuses ("CDR message size mismatch")
BYTE_SEQUENCES_OK = {"uint8", "int8", "byte", "char", "bool", "string", "wstring"}


def _share_dirs() -> list[Path]:
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p] + [sys.prefix]
    return [Path(p) / "share" for p in dict.fromkeys(prefixes)]


def _interface_file(type_name: str, suffix: str) -> Path:
    package, _, name = type_name.split("/")
    for share in _share_dirs():
        path = share / package / "msg" / f"{name}{suffix}"
        if path.is_file():
            return path
    raise FileNotFoundError(f"no {suffix} file for {type_name} under {[str(s) for s in _share_dirs()]}")


def _field_types(package: str, text: str) -> list[str]:
    """Full names (pkg/msg/Name) of the non-primitive field types of a .msg text (constants
    are always primitive, so they drop out with the primitives)."""
    types = []
    for line in text.splitlines():
        tokens = line.split("#", 1)[0].split()
        if len(tokens) < 2:
            continue
        base = re.sub(r"(<=\d+)?(\[.*\])?$", "", tokens[0])
        if base in PRIMITIVES:
            continue
        if base == "Header":
            types.append("std_msgs/msg/Header")
        elif "/" in base:
            types.append(f"{base.split('/')[0]}/msg/{base.split('/')[-1]}")
        else:
            types.append(f"{package}/msg/{base}")
    return types


def _definitions(type_name: str) -> list[tuple[str, str]]:
    """(pkg/msg/Name, .msg text) of `type_name` and then of every message it contains, each once, depth first in
    field order."""
    seen, order, stack = set(), [], [type_name]
    while stack:
        name = stack.pop()
        if name in seen:
            continue
        seen.add(name)
        text = _interface_file(name, ".msg").read_text()
        order.append((name, text))
        stack.extend(reversed(_field_types(name.split("/")[0], text)))
    return order


def exact_encoding_needed(type_name: str) -> bool:
    """Whether `type_name` (pkg/msg/Name) or a message in it has a sequence of numbers wider than a byte."""
    for _, text in _definitions(type_name):
        for line in text.splitlines():
            tokens = line.split("#", 1)[0].split()
            if len(tokens) >= 2 and "=" not in tokens[1] and re.search(r"\[(<=)?\d*\]$", tokens[0]) and \
                    tokens[0].split("[")[0] in PRIMITIVES - BYTE_SEQUENCES_OK:
                return True
    return False


def message_definition(type_name: str) -> str:
    """The ros2msg schema text of `type_name` (pkg/msg/Name): its .msg text, then every
    dependency once, each after a separator line and `MSG: pkg/msg/Name`."""
    (_, root), *dependencies = _definitions(type_name)
    parts = [root.strip()] + [f"{SEPARATOR}\nMSG: {name}\n{text.strip()}" for name, text in dependencies]
    return "\n".join(parts) + "\n"


def type_description_hash(type_name: str) -> str:
    """RIHS01 type hash from the interface's installed .json description ('' if none)."""
    try:
        description = json.loads(_interface_file(type_name, ".json").read_text())
    except FileNotFoundError:
        return ""
    for entry in description.get("type_hashes", []):
        if entry.get("type_name") == type_name:
            return entry["hash_string"]
    return ""


@dataclass(frozen=True)
class TopicQos:
    """The offered QoS recorded for a topic (rosbag2 metadata)."""

    reliable: bool = True
    transient_local: bool = False
    depth: int = 10

    def as_metadata(self) -> list[dict[str, Any]]:
        def infinite() -> dict[str, int]:
            return {"sec": INFINITE_S, "nsec": INFINITE_NS}

        return [{
            "history": "keep_last", "depth": self.depth,
            "reliability": "reliable" if self.reliable else "best_effort",
            "durability": "transient_local" if self.transient_local else "volatile",
            "deadline": infinite(), "lifespan": infinite(), "liveliness": "automatic",
            "liveliness_lease_duration": infinite(), "avoid_ros_namespace_conventions": False,
        }]


class BagWriter:
    """Writes one rosbag2 bag (see the module docstring). Use as a context manager or call
    close(); abort() discards an unfinished bag."""

    def __init__(self, directory: str | Path):
        self.path = Path(directory)
        if self.path.exists():
            raise FileExistsError(f"bag {self.path} already exists")
        self._partial = self.path.with_name(self.path.name + ".partial")
        self._partial.mkdir(parents=True)
        self._file_name = f"{self.path.name}_0.mcap"
        self._stream = open(self._partial / self._file_name, "wb")
        self._writer = McapWriter(self._stream, compression=CompressionType.NONE)
        self._writer.start(profile="ros2", library="cito_ros")
        self._schemas: dict[str, tuple[int, Any]] = {}  # type -> (schema id, CDR encoder of message objects)
        self._topics: dict[str, dict[str, Any]] = {}
        self._times: list[int] = []
        self.closed = False

    def add_topic(self, topic: str, type_name: str, qos: TopicQos = TopicQos()) -> None:
        if topic in self._topics:
            raise ValueError(f"topic {topic} is already in the bag")
        if type_name not in self._schemas:
            text = message_definition(type_name)
            schema = self._writer.register_schema(type_name, SchemaEncoding.ROS2, text.encode())
            encode = serialize_dynamic(type_name, text)[type_name] if exact_encoding_needed(type_name) \
                else serialize_message
            self._schemas[type_name] = (schema, encode)
        channel = self._writer.register_channel(
            topic, MessageEncoding.CDR, self._schemas[type_name][0],
            metadata={"offered_qos_profiles": yaml.safe_dump(qos.as_metadata(), sort_keys=False)})
        self._topics[topic] = {"type": type_name, "qos": qos, "count": 0, "channel": channel}

    def write(self, topic: str, message: Any, time_ns: int) -> None:
        """Write a message (its CDR bytes, or a ROS message object) with log and publish time time_ns."""
        if self.closed:
            raise ValueError("the bag is closed")
        entry = self._topics[topic]
        data = message if isinstance(message, bytes) else self._schemas[entry["type"]][1](message)
        self._writer.add_message(entry["channel"], log_time=time_ns, data=data, publish_time=time_ns,
                                 sequence=entry["count"])
        entry["count"] += 1
        self._times.append(time_ns)

    def close(self) -> Path:
        """Finish the MCAP file and metadata, sync, and move the bag to its final name."""
        if self.closed:
            return self.path
        self._writer.finish()
        self._stream.flush()
        os.fsync(self._stream.fileno())
        self._stream.close()
        start = min(self._times, default=0)
        duration = max(self._times, default=0) - start
        count = len(self._times)
        metadata = {"rosbag2_bagfile_information": {
            "version": 9,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": count,
            "topics_with_message_count": [{
                "topic_metadata": {
                    "name": topic, "type": entry["type"], "serialization_format": "cdr",
                    "offered_qos_profiles": entry["qos"].as_metadata(),
                    "type_description_hash": type_description_hash(entry["type"]),
                },
                "message_count": entry["count"],
            } for topic, entry in self._topics.items()],
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [self._file_name],
            "files": [{"path": self._file_name, "starting_time": {"nanoseconds_since_epoch": start},
                       "duration": {"nanoseconds": duration}, "message_count": count}],
            "custom_data": {},
            "ros_distro": "jazzy",
        }}
        with open(self._partial / "metadata.yaml", "w", encoding="utf-8") as stream:
            yaml.safe_dump(metadata, stream, sort_keys=False)
            stream.flush()
            os.fsync(stream.fileno())
        os.rename(self._partial, self.path)
        directory = os.open(self.path.parent, os.O_RDONLY)
        try:
            os.fsync(directory)
        finally:
            os.close(directory)
        self.closed = True
        return self.path

    def abort(self) -> None:
        """Discard an unfinished bag."""
        if self.closed:
            return
        self._stream.close()
        for child in self._partial.iterdir():
            child.unlink()
        self._partial.rmdir()
        self.closed = True

    def __enter__(self) -> "BagWriter":
        return self

    def __exit__(self, exc_type, exc, traceback) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
