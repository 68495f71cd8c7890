"""A whole session, whatever path names it: `info` over every split file, and `recover` of a bag.

`find_session` (bag.py) turns a bag folder, any of its files, or a lone MCAP file into the ordered
list of files; here they are described as one (counts and time span over all files) and a bag left
by a crash is made whole again: its cut files recovered, its `metadata.yaml` rebuilt from the files.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

from drivers.sessions.mcap.bag import (
    FileStats,
    TopicStats,
    bag_file,
    bag_folder,
    clear_bag,
    find_session,
    write_metadata,
)
from drivers.sessions.mcap.errors import LogFileError
from drivers.sessions.mcap.info import ChannelInfo, LogInfo, rate_hz, read_info
from drivers.sessions.mcap.recover import RecoverReport, recover
from drivers.sessions.mcap.writer import METADATA_NAME

_NS_PER_S = 1e9
_RECOVERING_SUFFIX = ".recovering"


def session_size(path: str | Path) -> int:
    """Bytes of every file of the session (for a progress bar); 0 when the path names none."""
    try:
        return sum(p.stat().st_size for p in find_session(path).files)
    except (LogFileError, OSError):
        return 0


def read_session_info(path: str | Path, progress: Callable[[int], None] | None = None,
                      verify: bool = True) -> LogInfo:
    """`read_info` of every file of the session, as one: counts summed, time span and rates over all
    files, complete only when every file is. For a bag, `bag` and `files` name its folder and files."""
    session = find_session(path)
    infos = [read_info(p, progress=progress, verify=verify) for p in session.files]
    if session.bag is None:
        return infos[0]
    return merge_infos(str(session.bag), infos)


def merge_infos(path: str, infos: list[LogInfo]) -> LogInfo:
    channels: dict[str, ChannelInfo] = {}
    for info in infos:
        for c in info.channels:
            seen = channels.get(c.topic)
            if seen is None:
                channels[c.topic] = c
                continue
            firsts = [t for t in (seen.first_log_time_ns, c.first_log_time_ns) if t is not None]
            lasts = [t for t in (seen.last_log_time_ns, c.last_log_time_ns) if t is not None]
            channels[c.topic] = replace(seen, message_count=seen.message_count + c.message_count,
                                        first_log_time_ns=min(firsts) if firsts else None,
                                        last_log_time_ns=max(lasts) if lasts else None)
    merged = tuple(replace(c, rate_hz=rate_hz(c.message_count, c.first_log_time_ns, c.last_log_time_ns))
                   for c in channels.values())
    starts = [i.start_ns for i in infos if i.start_ns is not None]
    ends = [i.end_ns for i in infos if i.end_ns is not None]
    start, end = (min(starts), max(ends)) if starts and ends else (None, None)
    first = infos[0]
    return LogInfo(
        path=path, size_bytes=sum(i.size_bytes for i in infos), profile=first.profile, library=first.library,
        has_summary=all(i.has_summary for i in infos), complete=all(i.complete for i in infos),
        unreadable_bytes=sum(i.unreadable_bytes for i in infos),
        damaged_chunks=sum(i.damaged_chunks for i in infos),
        message_count=sum(i.message_count for i in infos), chunk_count=sum(i.chunk_count for i in infos),
        start_ns=start, end_ns=end,
        duration_s=(end - start) / _NS_PER_S if start is not None and end is not None else 0.0,
        compression=tuple(sorted({c for i in infos for c in i.compression})),
        channels=merged, metadata=first.metadata, bag=path, files=tuple(i.path for i in infos),
        incomplete_files=tuple(i.path for i in infos if not i.complete),
    )


def rebuild_metadata(folder: Path, files: list[Path]) -> Path:
    """Write `folder/metadata.yaml` from what the (whole) files hold, as `ros2 bag reindex` does."""
    infos = [read_info(p, verify=False) for p in files]
    topics: dict[str, TopicStats] = {}
    for info in infos:
        for c in info.channels:
            seen = topics.get(c.topic)
            count = c.message_count + (seen.message_count if seen else 0)
            topics[c.topic] = TopicStats(c.topic, c.type_name, count)
    stats = [FileStats(p.name, i.message_count, i.start_ns, i.end_ns)
             for p, i in zip(files, infos, strict=True)]
    custom = next((dict(m.entries) for i in infos for m in i.metadata if m.name == METADATA_NAME), {})
    custom.pop("part", None)  # per file, not the session's
    return write_metadata(folder, stats, topics.values(), custom)


@dataclass(frozen=True)
class SessionRecoverReport:
    """`recover` of a bag: the files rewritten (each with its report), those left as they were
    (already whole), and the metadata written. data_lost: some file lost data."""

    bag: str
    output: str
    recovered: tuple[RecoverReport, ...]
    untouched: tuple[str, ...]
    metadata: str

    @property
    def data_lost(self) -> bool:
        return any(r.data_lost for r in self.recovered)

    def to_json_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["recovered"] = [r.to_json_dict() for r in self.recovered]
        out["untouched"] = list(self.untouched)
        out["data_lost"] = self.data_lost
        return out


def recover_bag(path: str | Path, output: str | Path | None = None,
                progress: Callable[[int], None] | None = None) -> SessionRecoverReport:
    """Make the bag `path` names readable: without `output`, in place (every cut or damaged file is
    replaced by what survives of it; whole files are left alone); with `output`, as a new bag there
    (every file copied through `recover`). Then `metadata.yaml` is rebuilt from the files."""
    session = find_session(path)
    if session.bag is None:
        raise LogFileError(session.named, "not a bag folder nor a file of one")
    folder = session.bag
    recovered: list[RecoverReport] = []
    untouched: list[str] = []
    if output is None:
        for p in session.files:
            info = read_info(p, progress=progress)
            if info.complete and info.has_summary:
                untouched.append(str(p))
                continue
            partial = p.with_name(p.name + _RECOVERING_SUFFIX)
            report = recover(p, partial)
            os.replace(partial, p)
            recovered.append(replace(report, output=str(p)))
        target, files = folder, list(session.files)
    else:
        target = bag_folder(output)
        if target.resolve() == folder.resolve():
            raise LogFileError(target, "the output must not be the bag being recovered (leave -o out "
                                       "to recover it in place)")
        try:
            target.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise LogFileError(target, f"cannot create: {exc.strerror or exc}") from exc
        clear_bag(target)
        files = [bag_file(target, i) for i in range(len(session.files))]
        for src, dst in zip(session.files, files, strict=True):
            recovered.append(recover(src, dst, progress=progress))
    metadata = rebuild_metadata(target, files)
    return SessionRecoverReport(str(folder), str(target), tuple(recovered), tuple(untouched), str(metadata))
