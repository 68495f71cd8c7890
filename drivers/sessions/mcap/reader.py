"""Reading a session's messages back in log-time order, with a topic and time-window filter.

Reads whole files (with a summary): a session (a bag folder or any of its files: every split file),
a lone file, or the output of `recover`. Several files are merged into one log-time ordered stream.
"""

from __future__ import annotations

import heapq
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import NamedTuple

from mcap.exceptions import McapError
from mcap.reader import SeekingReader

from drivers.sessions.mcap.bag import find_session
from drivers.sessions.mcap.errors import LogFileError
from drivers.sessions.mcap.scan import open_log


class LoggedMessage(NamedTuple):
    """One recorded message; unpacks as (topic, type_name, msgdef, data, log_time_ns, publish_time_ns)."""

    topic: str
    type_name: str
    msgdef: str
    data: bytes
    log_time_ns: int
    publish_time_ns: int


def iter_messages(
    paths: str | Path | Sequence[str | Path],
    *,
    topics: Iterable[str] | None = None,
    start_ns: int | None = None,
    end_ns: int | None = None,
) -> Iterator[LoggedMessage]:
    """Messages of a session (one path: a bag folder, any of its files, or a lone file) or of the
    files listed, in log-time order.

    topics: keep only these topics (None: all). start_ns/end_ns: keep log times in [start_ns, end_ns).
    Raises LogFileError for a missing, non-MCAP or cut-short file (the latter: run `log recover`).
    """
    if isinstance(paths, (str, Path)):
        paths = list(find_session(paths).files)
    if start_ns is not None and end_ns is not None and start_ns > end_ns:
        raise ValueError(f"start_ns ({start_ns}) is after end_ns ({end_ns})")
    wanted = None if topics is None else sorted(set(topics))
    streams = [_iter_file(Path(p), i, wanted, start_ns, end_ns) for i, p in enumerate(paths)]
    if len(streams) == 1:
        for _, _, msg in streams[0]:
            yield msg
        return
    # Ties in log time keep file order, then order within the file.
    for _, _, msg in heapq.merge(*streams, key=lambda item: (item[0], item[1])):
        yield msg


def _iter_file(path: Path, file_index: int, topics: list[str] | None, start_ns: int | None,
               end_ns: int | None) -> Iterator[tuple[int, int, LoggedMessage]]:
    f, _ = open_log(path)
    with f:
        f.seek(0)
        try:
            reader = SeekingReader(f, validate_crcs=True)
            reader.get_summary()
        except (McapError, ValueError, EOFError, OSError) as exc:
            raise LogFileError(path, f"cannot read the footer/summary ({exc or type(exc).__name__}); "
                                     "if the file was cut short, run `foldcell log recover` first") from exc
        try:
            for schema, channel, message in reader.iter_messages(
                    topics=topics, starting_at=start_ns, ending_before=end_ns, log_time_order=True):
                yield message.log_time, file_index, LoggedMessage(
                    topic=channel.topic,
                    type_name=schema.name if schema is not None else "",
                    msgdef=schema.data.decode() if schema is not None else "",
                    data=bytes(message.data),
                    log_time_ns=message.log_time,
                    publish_time_ns=message.publish_time,
                )
        except (McapError, ValueError, EOFError) as exc:
            raise LogFileError(path, f"damaged: {exc or type(exc).__name__}; "
                                     "run `foldcell log recover` to keep what is readable") from exc
