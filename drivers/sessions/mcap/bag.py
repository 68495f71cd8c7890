"""A session as a rosbag2 bag: the folder, its file names, the QoS of a topic, and `metadata.yaml`.

A bag is a folder `NAME/` holding `NAME_0.mcap`, `NAME_1.mcap`, ... (split by size, in that order)
and `metadata.yaml`, as `ros2 bag record -s mcap -o NAME` leaves it. The metadata is rosbag2's
version 9 (ROS 2 Jazzy, whose message definitions the session carries): QoS profiles as a list,
RIHS01 type hashes, per-file start, duration and count. A session path ending in `.mcap` names the
bag folder without that suffix (`runs/x.mcap` -> `runs/x/x_0.mcap`), so a path given as a file name
keeps working.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import yaml

from drivers.sessions.mcap.errors import LogFileError
from drivers.wire import messages
from drivers.wire.messages import WireError
from drivers.wire.registry import spec_for, split_key

METADATA_FILE = "metadata.yaml"
BAG_VERSION = 9
STORAGE_IDENTIFIER = "mcap"
SERIALIZATION_FORMAT = "cdr"
ROS_DISTRO = "jazzy"
MCAP_SUFFIX = ".mcap"
# rosbag2's "no deadline / lifespan / lease": the largest rmw_time_t it writes
_INFINITE = {"sec": 9223372036, "nsec": 854775807}


def bag_folder(path: str | Path) -> Path:
    """The bag folder a session path names (`x.mcap` -> `x`; any other path is the folder)."""
    p = Path(path)
    return p.with_suffix("") if p.suffix == MCAP_SUFFIX else p


def bag_file(folder: Path, index: int) -> Path:
    """Split file `index` of the bag in `folder`, named as rosbag2 names it: `<folder name>_<index>.mcap`."""
    return folder / f"{folder.name}_{index}{MCAP_SUFFIX}"


def _split_index(folder: Path, path: Path) -> int | None:
    match = re.fullmatch(re.escape(folder.name) + r"_(\d+)" + re.escape(MCAP_SUFFIX), path.name)
    return int(match.group(1)) if match else None


def qos_profiles(topic: str) -> list[dict[str, Any]]:
    """The offered QoS of a topic, rosbag2 version 9 style: a stream that drops when congested is
    best effort, every other key (commands, states, logs) reliable; nothing is kept for late joiners."""
    try:
        best_effort = spec_for(split_key(topic.lstrip("/"))[1]).drop_when_congested
    except WireError:
        best_effort = False  # the recorder's own topics (/diagnostics/rejected) are kept whole
    return [{
        # Zenoh, like DDS, does not tell a subscriber the publisher's history: rosbag2 writes this then
        "history": "unknown",
        "depth": 0,
        "reliability": "best_effort" if best_effort else "reliable",
        "durability": "volatile",
        "deadline": dict(_INFINITE),
        "lifespan": dict(_INFINITE),
        "liveliness": "automatic",
        "liveliness_lease_duration": dict(_INFINITE),
        "avoid_ros_namespace_conventions": False,
    }]


def qos_text(topic: str) -> str:
    """The QoS profiles as the YAML text rosbag2's MCAP storage puts in a channel's metadata."""
    return yaml.safe_dump(qos_profiles(topic), default_flow_style=False, sort_keys=False).strip()


@cache
def type_hash(type_name: str) -> str:
    """The RIHS01 hash of a message type, as `ros2 bag` and rmw implementations compute it."""
    return str(messages.typestore().hash_rihs01(type_name))


@dataclass
class FileStats:
    """One split file: its name in the folder, the log-time range and count of its messages."""

    name: str
    message_count: int = 0
    start_ns: int | None = None
    end_ns: int | None = None

    def add(self, log_time_ns: int) -> None:
        self.message_count += 1
        self.start_ns = log_time_ns if self.start_ns is None else min(self.start_ns, log_time_ns)
        self.end_ns = log_time_ns if self.end_ns is None else max(self.end_ns, log_time_ns)


@dataclass(frozen=True)
class TopicStats:
    name: str
    type_name: str
    message_count: int


def metadata_document(files: Iterable[FileStats], topics: Iterable[TopicStats],
                      custom_data: Mapping[str, str] | None = None) -> dict[str, Any]:
    """The `metadata.yaml` content, keys in rosbag2's order."""
    files = list(files)
    starts = [f.start_ns for f in files if f.start_ns is not None]
    ends = [f.end_ns for f in files if f.end_ns is not None]
    start = min(starts) if starts else 0
    duration = max(ends) - start if ends else 0
    return {"rosbag2_bagfile_information": {
        "version": BAG_VERSION,
        "storage_identifier": STORAGE_IDENTIFIER,
        "duration": {"nanoseconds": duration},
        "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": sum(f.message_count for f in files),
        "topics_with_message_count": [{
            "topic_metadata": {
                "name": t.name,
                "type": t.type_name,
                "serialization_format": SERIALIZATION_FORMAT,
                "offered_qos_profiles": qos_profiles(t.name),
                "type_description_hash": type_hash(t.type_name),
            },
            "message_count": t.message_count,
        } for t in topics],
        "compression_format": "",
        "compression_mode": "",  # MCAP compresses its chunks itself
        "relative_file_paths": [f.name for f in files],
        "files": [{
            "path": f.name,
            "starting_time": {"nanoseconds_since_epoch": f.start_ns or 0},
            "duration": {"nanoseconds": (f.end_ns - f.start_ns)
                         if f.start_ns is not None and f.end_ns is not None else 0},
            "message_count": f.message_count,
        } for f in files],
        "custom_data": dict(custom_data) if custom_data else None,
        "ros_distro": ROS_DISTRO,
    }}


def write_metadata(folder: Path, files: Iterable[FileStats], topics: Iterable[TopicStats],
                   custom_data: Mapping[str, str] | None = None) -> Path:
    """Write `folder/metadata.yaml` atomically (a reader sees the old one or the new one)."""
    path = folder / METADATA_FILE
    text = yaml.safe_dump(metadata_document(files, topics, custom_data), default_flow_style=False,
                          sort_keys=False)
    partial = path.with_name(path.name + ".partial")
    try:
        partial.write_text(text)
        os.replace(partial, path)
    except OSError as exc:
        raise LogFileError(path, f"cannot write the bag's metadata: {exc.strerror or exc}") from exc
    return path


def listed_files(folder: Path) -> list[Path] | None:
    """The split files `metadata.yaml` lists, in order; None when there is no readable metadata."""
    try:
        document = yaml.safe_load((folder / METADATA_FILE).read_text())
        names = document["rosbag2_bagfile_information"]["relative_file_paths"]
    except (OSError, yaml.YAMLError, KeyError, TypeError):
        return None
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        return None
    return [folder / Path(n).name for n in names]


def split_files(folder: Path) -> list[Path]:
    """The `<folder name>_<n>.mcap` files present in `folder`, by n."""
    found = [(index, p) for p in folder.glob(f"*{MCAP_SUFFIX}")
             if (index := _split_index(folder, p)) is not None]
    return [p for _, p in sorted(found)]


def bag_files(folder: Path) -> list[Path]:
    """A bag's files in order: those its metadata lists (and split files written after the metadata
    was, as a crash can leave them), or, without metadata, its `<name>_<n>.mcap` files."""
    listed = listed_files(folder)
    on_disk = split_files(folder)
    if listed is None:
        return on_disk
    missing = [p.name for p in listed if not p.is_file()]
    if missing:
        raise LogFileError(folder, f"{METADATA_FILE} lists files that are not there: {', '.join(missing)}")
    return listed + [p for p in on_disk if p not in listed]


def is_bag_file(path: Path) -> bool:
    """True when `path` is one split file of the bag in its folder."""
    folder = path.parent
    listed = listed_files(folder)
    return path in listed if listed is not None else _split_index(folder, path) is not None


@dataclass(frozen=True)
class SessionFiles:
    """What a session path names: the bag folder (None for a lone MCAP file) and its files in order."""

    named: Path
    bag: Path | None
    files: tuple[Path, ...]

    @property
    def path(self) -> Path:
        """The session as one path: the bag folder, or the lone file."""
        return self.bag if self.bag is not None else self.files[0]


def find_session(path: str | Path) -> SessionFiles:
    """The session a path names: a bag folder, any file of a bag, `x.mcap` for the bag `x/`, or a
    lone MCAP file. Raises LogFileError naming the path when it names none."""
    p = Path(path)
    if p.is_dir():
        folder = p
    elif p.is_file():
        if not is_bag_file(p):
            return SessionFiles(p, None, (p,))
        folder = p.parent
    elif bag_folder(p) != p and bag_folder(p).is_dir():
        folder = bag_folder(p)
    else:
        raise LogFileError(p, "no such file or bag folder")
    files = bag_files(folder)
    if not files:
        raise LogFileError(folder, f"not a session: no {METADATA_FILE} and no "
                                   f"{folder.name}_<n>{MCAP_SUFFIX} file in this folder")
    return SessionFiles(p, folder, tuple(files))


def clear_bag(folder: Path) -> list[Path]:
    """Remove the files of a session recorded before in `folder` (a new one replaces it, as a
    recorder given the same file name always did). Returns what was removed."""
    if not folder.is_dir():
        return []
    stale = split_files(folder) + [p for p in (listed_files(folder) or []) if p.is_file()]
    stale += [folder / METADATA_FILE] if (folder / METADATA_FILE).exists() else []
    removed = []
    for p in dict.fromkeys(stale):
        try:
            p.unlink()
        except OSError as exc:
            raise LogFileError(p, "cannot replace the earlier session's file: "
                                  f"{exc.strerror or exc}") from exc
        removed.append(p)
    return removed
