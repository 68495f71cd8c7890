"""Replaying a logged session: selection, timing, pause/step, and republishing on the wire.

The engine (`Replayer`) is pure: it takes the messages and a sink callable, so its timing and
selection are tested without Zenoh. `WireSink` republishes each sample's recorded bytes on its key
in a cell of its own (`<recorded cell>-replay`, or the one given), never into a live cell, with the
original sender stamp in the attachment.
A session is a bag folder (or any of its files) or a lone MCAP file; every split file is read, in
order. A file cut short by a crash is first recovered into a temporary file (`open_session`).
"""

from __future__ import annotations

import fnmatch
import logging
import os
import tempfile
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from drivers.common.configfile import Fields, config_dir, load_yaml
from drivers.sessions.mcap.bag import find_session
from drivers.sessions.mcap.errors import LogFileError
from drivers.sessions.mcap.info import LogInfo, read_info
from drivers.sessions.mcap.reader import LoggedMessage, iter_messages
from drivers.sessions.mcap.recover import recover
from drivers.wire.messages import WireError
from drivers.wire.registry import spec_for, split_key
from drivers.wire.security import REPLAY_SUFFIX, replay_cell_id
from drivers.wire.settings import WireSettings, check_cell_id

if TYPE_CHECKING:
    from drivers.wire.transport import TypedPublisher, Wire

log = logging.getLogger(__name__)

CONFIG_FILE = "replay_monitor.yaml"
NS = 1_000_000_000
LIVE_CHECK_S = 1.0   # how long a replay waits for a cell's processes to say they are alive


class ReplayError(ValueError):
    """A replay that cannot start: names the argument or file and the reason."""


class CellRefusedError(ReplayError):
    """A cell a replay must not publish into: a live one, or on a secured wire one the router keeps a
    replay out of."""


@dataclass(frozen=True)
class ReplayConfig:
    subscriber_wait_s: float
    max_sleep_s: float
    progress_update_s: float
    step_keys: tuple[str, ...]
    pause_keys: tuple[str, ...]
    quit_keys: tuple[str, ...]


def replay_config_from_fields(f: Fields) -> ReplayConfig:
    f.reject_unknown(
        {"subscriber_wait_s", "max_sleep_s", "progress_update_s", "step_keys", "pause_keys", "quit_keys"}
    )
    return ReplayConfig(
        subscriber_wait_s=f.float("subscriber_wait_s", min=0.0),
        max_sleep_s=f.float("max_sleep_s", min=1e-4),
        progress_update_s=f.float("progress_update_s", min=1e-3),
        step_keys=f.strs("step_keys"),
        pause_keys=f.strs("pause_keys"),
        quit_keys=f.strs("quit_keys"),
    )


def load_replay_config(path: str | Path | None = None) -> ReplayConfig:
    return replay_config_from_fields(
        load_yaml(Path(path) if path else config_dir() / CONFIG_FILE).sub("replay")
    )


# --- selection -------------------------------------------------------------------------------


@dataclass(frozen=True)
class TopicFilter:
    """Globs (fnmatch; `*` also crosses `/`) on the key, with or without `foldcell/<cell>/`.

    A topic is kept when it matches some include (or there is none) and no exclude.
    """

    include: tuple[str, ...] = ()
    exclude: tuple[str, ...] = ()

    @staticmethod
    def parse(globs: Iterable[str], excludes: Iterable[str] = ()) -> TopicFilter:
        """`--topics` values; one starting with `!` excludes."""
        inc: list[str] = []
        exc: list[str] = list(excludes)
        for g in globs:
            g = g.strip()
            if not g or g == "!":
                raise ReplayError(f"--topics: empty glob in {list(globs)!r}")
            (exc if g.startswith("!") else inc).append(g.removeprefix("!"))
        return TopicFilter(tuple(inc), tuple(exc))

    def keeps(self, topic: str) -> bool:
        names = _names_of(topic)
        if self.include and not any(fnmatch.fnmatchcase(n, g) for g in self.include for n in names):
            return False
        return not any(fnmatch.fnmatchcase(n, g) for g in self.exclude for n in names)


def _names_of(topic: str) -> tuple[str, ...]:
    key = topic.lstrip("/")
    try:
        rel = split_key(key)[1]
    except WireError:
        return (topic, key)
    return (topic, key, rel)


def topic_key(topic: str) -> str:
    """A logged topic's key relative to its cell (`/foldcell/a/camera/image` -> `camera/image`)."""
    return _names_of(topic)[-1]


def retarget(topic: str, cell: str | None) -> str:
    """The full key a logged topic is republished on: `/foldcell/a/x` -> `foldcell/<cell>/x`, by
    default `foldcell/a-replay/x`."""
    recorded, rel = split_key(topic.lstrip("/"))
    return f"foldcell/{cell or replay_cell_id(recorded)}/{rel}"


@dataclass(frozen=True)
class Session:
    """A session ready to read: `paths` are its files in order (a recovered copy stands in for a
    file cut short); `source` is the bag folder, or the lone file, that was named."""

    source: Path
    paths: tuple[Path, ...]
    start_ns: int
    end_ns: int
    topics: tuple[str, ...]
    recovered: bool
    messages_lost: bool = False
    temp_dir: str | None = None

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / NS

    def close(self) -> None:
        if self.temp_dir is not None:
            for p in Path(self.temp_dir).iterdir():
                p.unlink(missing_ok=True)
            os.rmdir(self.temp_dir)


def open_session(path: str | Path) -> Session:
    """Look at a session (bag folder, one of its files, or a lone file); a file cut short by a crash
    is recovered to a temporary copy first."""
    try:
        found = find_session(path)
        infos = [read_info(p) for p in found.files]
    except LogFileError as exc:
        raise ReplayError(str(exc)) from exc
    temp_dir: str | None = None
    paths: list[Path] = []
    lost = False
    try:
        for index, (src, info) in enumerate(zip(found.files, infos, strict=True)):
            if info.complete and info.has_summary:
                paths.append(src)
                continue
            temp_dir = temp_dir or tempfile.mkdtemp(prefix="foldcell-replay-")
            dst = Path(temp_dir) / f"{index}-{src.stem}.recovered.mcap"
            try:
                report = recover(src, dst)
                infos[index] = read_info(dst)
            except LogFileError as exc:
                raise ReplayError(f"{src}: cut short or damaged, and not recoverable: {exc}") from exc
            log.warning("%s is cut short or damaged: reading the %d messages of its intact chunks",
                        src, report.messages_kept)
            lost = lost or report.data_lost
            paths.append(dst)
    except BaseException:
        if temp_dir is not None:
            Session(found.path, (), 0, 0, (), False, temp_dir=temp_dir).close()
        raise
    return Session(found.path, tuple(paths), *_span(infos), recovered=temp_dir is not None,
                   messages_lost=lost, temp_dir=temp_dir)


def _span(infos: list[LogInfo]) -> tuple[int, int, tuple[str, ...]]:
    """Start, end and topics (in order of first appearance) over every file."""
    starts = [i.start_ns for i in infos if i.start_ns is not None]
    ends = [i.end_ns for i in infos if i.end_ns is not None]
    topics = dict.fromkeys(c.topic for i in infos for c in i.channels)
    return min(starts, default=0), max(ends, default=0), tuple(topics)


@dataclass(frozen=True)
class Selection:
    """What to replay: a window in seconds into the session and a topic filter."""

    start_s: float | None = None
    end_s: float | None = None
    topics: TopicFilter = field(default_factory=TopicFilter)

    def __post_init__(self) -> None:
        if self.start_s is not None and self.start_s < 0:
            raise ReplayError(f"--start: must be >= 0 s, got {self.start_s:g}")
        if self.end_s is not None and self.end_s < 0:
            raise ReplayError(f"--end: must be >= 0 s, got {self.end_s:g}")
        if self.start_s is not None and self.end_s is not None and self.end_s <= self.start_s:
            raise ReplayError(f"--end ({self.end_s:g} s) must be after --start ({self.start_s:g} s)")

    def window_ns(self, session: Session) -> tuple[int | None, int | None]:
        start = None if self.start_s is None else session.start_ns + round(self.start_s * NS)
        end = None if self.end_s is None else session.start_ns + round(self.end_s * NS)
        return start, end


def select(session: Session, selection: Selection) -> Iterator[LoggedMessage]:
    """The session's messages in log-time order, restricted to the window and the topics."""
    topics = [t for t in session.topics if selection.topics.keeps(t)]
    if not topics:
        return iter(())
    start, end = selection.window_ns(session)
    return iter_messages(session.paths, topics=topics, start_ns=start, end_ns=end)


# --- timing ----------------------------------------------------------------------------------


@dataclass
class ReplayStats:
    published: int = 0
    skipped: int = 0
    loops: int = 0
    lateness_ns: list[int] = field(default_factory=list)  # filled when record_lateness
    stopped: bool = False


class Replayer:
    """Publishes messages at `rate` times their recorded pace (rate None: as fast as possible).

    Controls (thread-safe, e.g. from the keyboard): `toggle_pause`, `step` (one message while
    paused), `stop`. Timing re-anchors after a pause or step, so the pause is not made up for.
    """

    def __init__(
        self,
        messages: Callable[[], Iterable[LoggedMessage]],
        sink: Callable[[LoggedMessage], bool],
        *,
        rate: float | None,
        loop: bool,
        config: ReplayConfig,
        clock: Callable[[], int] = time.monotonic_ns,
        sleep: Callable[[float], None] = time.sleep,
        record_lateness: bool = False,
    ):
        if rate is not None and rate <= 0:
            raise ReplayError(f"--rate: must be > 0 (or 'max'), got {rate:g}")
        self.messages = messages
        self.sink = sink
        self.rate = rate
        self.loop = loop
        self.config = config
        self.clock = clock  # ns
        self.sleep = sleep  # s; with `clock`, a virtual time base for tests of the pacing
        self.record_lateness = record_lateness
        self.cond = threading.Condition()
        self.paused = False
        self.steps = 0
        self.stopping = False
        self.position_ns = 0  # log time of the last message published
        self.stats = ReplayStats()

    # controls
    def toggle_pause(self) -> bool:
        with self.cond:
            self.paused = not self.paused
            self.cond.notify_all()
            return self.paused

    def step(self) -> None:
        with self.cond:
            self.paused = True
            self.steps += 1
            self.cond.notify_all()

    def stop(self) -> None:
        with self.cond:
            self.stopping = True
            self.cond.notify_all()

    # running
    def run(self, progress: Callable[[int], None] | None = None) -> ReplayStats:
        """Replay until the end (or forever with loop) or `stop`; returns what was published."""
        while not self.stopping:
            count = self._one_pass(progress)
            self.stats.loops += 1
            if not self.loop or count == 0:
                break
        self.stats.stopped = self.stopping
        return self.stats

    def _one_pass(self, progress: Callable[[int], None] | None) -> int:
        anchor_wall: int | None = None
        anchor_log = 0
        count = 0
        for msg in self.messages():
            # wait while paused; a step lets exactly one message through
            stepped = False
            with self.cond:
                while self.paused and not self.stopping and self.steps == 0:
                    self.cond.wait(self.config.max_sleep_s)
                if self.stopping:
                    break
                if self.paused and self.steps > 0:
                    self.steps -= 1
                    stepped = True
            if anchor_wall is None or stepped or self._resumed:
                anchor_wall, anchor_log = self.clock(), msg.log_time_ns
                self._resumed = False
            due = (
                anchor_wall
                if self.rate is None
                else anchor_wall + round((msg.log_time_ns - anchor_log) / self.rate)
            )
            if self.rate is not None and not stepped and not self._sleep_until(due):
                break  # stopped, or paused meanwhile: the message is retried after the pause
            now = self.clock()
            if self.sink(msg):
                self.stats.published += 1
            else:
                self.stats.skipped += 1
            if self.record_lateness and self.rate is not None and not stepped:
                self.stats.lateness_ns.append(now - due)
            count += 1
            self.position_ns = msg.log_time_ns
            if progress is not None:
                progress(msg.log_time_ns)
        return count

    _resumed = False

    def _sleep_until(self, due: int) -> bool:
        """Sleep to `due` in short slices; False when stopped. A pause holds here until resumed."""
        while True:
            with self.cond:
                if self.stopping:
                    return False
                if self.paused:
                    while self.paused and not self.stopping and self.steps == 0:
                        self.cond.wait(self.config.max_sleep_s)
                    if self.stopping:
                        return False
                    if self.steps > 0:
                        self.steps -= 1
                    self._resumed = True
                    return True
            remaining = due - self.clock()
            if remaining <= 0:
                return True
            self.sleep(min(remaining / NS, self.config.max_sleep_s))


# --- the wire --------------------------------------------------------------------------------


class WireSink:
    """Republishes logged samples on Zenoh, one Wire (and liveliness token) per cell replayed into.

    Each Wire holds `alive/<process>` (process `cli-replay-<pid>` by default), so a monitor sees the
    cell's samples come from a replay. Keys outside the registry's published keys are skipped. A cell
    where the cell daemon or a controller is alive is refused: replayed samples would be taken for
    the robot's own.
    """

    def __init__(self, settings: WireSettings, *, cell: str | None, process: str):
        from drivers.wire.transport import TypedPublisher, Wire  # the pure engine above needs no Zenoh

        self._wire_class = Wire
        self._publisher_class = TypedPublisher
        self.settings = settings
        self.cell = check_cell_id(cell, "--cell") if cell else None
        if settings.security is not None and self.cell and not self.cell.endswith(REPLAY_SUFFIX):
            raise CellRefusedError(f"--cell: {self.cell!r}: on a secured cell a replay publishes only in "
                                   f"a cell id ending in {REPLAY_SUFFIX!r} (the router drops the rest)")
        self.process = process
        self.wires: dict[str, Wire] = {}
        self.publishers: dict[str, TypedPublisher] = {}
        self.unknown: set[str] = set()

    def _publisher(self, topic: str) -> TypedPublisher | None:
        pub = self.publishers.get(topic)
        if pub is not None or topic in self.unknown:
            return pub
        try:
            cell, rel = split_key(retarget(topic, self.cell))
            if spec_for(rel).kind != "pub":
                raise WireError(rel, "not a published key")
        except WireError as err:
            log.warning("not replayed: %s (%s)", topic, err)
            self.unknown.add(topic)
            return None
        wire = self.wires.get(cell)
        if wire is None:
            wire = self._wire_class(self.settings.overridden(cell_id=cell), self.process, announce=False)
            self.wires[cell] = wire
            alive = (split_key(key)[1].removeprefix("alive/") for key in wire.alive(timeout=LIVE_CHECK_S))
            live = sorted(name for name in alive if name == "cell" or name.startswith("controller"))
            if live:
                raise CellRefusedError(f"--cell: {cell} is a live cell ({', '.join(live)} alive there); "
                                       "a replay goes to a cell of its own: leave out --cell "
                                       "(<cell>-replay) or name another")
            wire.announce()
        # Never dropped, unlike the live stream: a replay republishes every sample, and at
        # --rate max it is paced by what the subscribers take.
        pub = self._publisher_class(wire, rel, spec_for(rel).type_name, False)
        self.publishers[topic] = pub
        return pub

    def prepare(self, topics: Iterable[str], wait_s: float) -> None:
        """Declare every publisher now and wait (bounded) for subscribers, so no first sample is lost."""
        pubs = [p for p in (self._publisher(t) for t in topics) if p is not None]
        deadline = time.monotonic() + wait_s
        matched = [p.wait_for_subscribers(max(0.0, deadline - time.monotonic())) for p in pubs]
        if pubs and not any(matched):
            log.warning("no subscriber within %.1f s: replaying anyway", wait_s)

    def __call__(self, msg: LoggedMessage) -> bool:
        pub = self._publisher(msg.topic)
        if pub is None:
            return False
        pub.put_encoded(msg.data, msg.publish_time_ns or msg.log_time_ns)
        return True

    def close(self) -> None:
        for pub in self.publishers.values():
            try:
                pub.undeclare()
            except Exception:  # the session is closed next anyway
                log.debug("undeclare failed", exc_info=True)
        for wire in self.wires.values():
            wire.close()


# --- perception again, offline (`replay --perceive`) -------------------------------------------
