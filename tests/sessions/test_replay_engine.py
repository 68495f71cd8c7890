"""The replay engine without Zenoh: selection, retargeting, timing, pause and step."""

from __future__ import annotations

import threading
import time

import pytest

from drivers.sessions.mcap.reader import LoggedMessage
from drivers.sessions.replay import (
    ReplayConfig,
    Replayer,
    ReplayError,
    Selection,
    Session,
    TopicFilter,
    load_replay_config,
    retarget,
)
from tests.conftest import wait_until
from tools.replay_cli import parse_rate

MS = 1_000_000


def msgs(times_ms: list[float], topics: list[str] | None = None) -> list[LoggedMessage]:
    topics = topics or ["/foldcell/a/cell/state"] * len(times_ms)
    return [
        LoggedMessage(t, "x", "", bytes([i % 256]), int(ms * MS), int(ms * MS) - 5)
        for i, (ms, t) in enumerate(zip(times_ms, topics, strict=False))
    ]


@pytest.fixture
def config() -> ReplayConfig:
    return load_replay_config()


def test_topic_filter_matches_relative_and_full_keys() -> None:
    f = TopicFilter.parse(["controller/*", "!controller/status"])
    assert f.keeps("/foldcell/c1/controller/joint_states")
    assert f.keeps("/foldcell/other/controller/gripper/r1")
    assert not f.keeps("/foldcell/c1/controller/status")
    assert not f.keeps("/foldcell/c1/cell/state")
    assert TopicFilter.parse(["foldcell/c1/**"]).keeps("/foldcell/c1/cell/log")
    assert not TopicFilter.parse(["foldcell/c1/*"], ["*log"]).keeps("/foldcell/c1/cell/log")
    assert TopicFilter().keeps("/anything")
    with pytest.raises(ReplayError, match="--topics"):
        TopicFilter.parse(["!"])


def test_retarget_moves_a_topic_into_another_cell() -> None:
    assert (
        retarget("/foldcell/c1/controller/joint_states", "replay1")
        == "foldcell/replay1/controller/joint_states"
    )
    # by default a cell of its own, never the recorded (maybe live) one
    assert retarget("/foldcell/c1/cell/state", None) == "foldcell/c1-replay/cell/state"
    assert retarget("/foldcell/c1-replay/cell/state", None) == "foldcell/c1-replay/cell/state"


def test_selection_window_is_relative_to_the_session_start() -> None:
    session = Session(
        source=None,
        paths=(),
        start_ns=10 * 10**9,
        end_ns=20 * 10**9,
        topics=(),  # type: ignore[arg-type]
        recovered=False,
    )
    assert Selection(1.5, 3.0).window_ns(session) == (11_500_000_000, 13_000_000_000)
    assert Selection().window_ns(session) == (None, None)
    for bad in ((-1.0, None), (None, -2.0), (3.0, 2.0), (2.0, 2.0)):
        with pytest.raises(ReplayError):
            Selection(*bad)


@pytest.mark.parametrize("text,rate", [("1", 1.0), ("5", 5.0), ("0.5", 0.5), ("max", None), ("MAX", None)])
def test_parse_rate(text: str, rate: float | None) -> None:
    assert parse_rate(text) == rate


@pytest.mark.parametrize("text", ["-1", "0", "abc", "nan"])
def test_parse_rate_rejects(text: str) -> None:
    with pytest.raises(ReplayError, match="--rate"):
        parse_rate(text)


def test_replay_publishes_everything_in_order_at_the_recorded_pace(config: ReplayConfig) -> None:
    data = msgs([0, 20, 40, 41, 90])
    seen: list[tuple[int, int]] = []
    r = Replayer(
        lambda: iter(data),
        lambda m: seen.append((m.log_time_ns, time.monotonic_ns())) or True,
        rate=2.0,
        loop=False,
        config=config,
        record_lateness=True,
    )
    stats = r.run()
    assert [s[0] for s in seen] == [m.log_time_ns for m in data]
    assert stats.published == 5 and stats.loops == 1
    # at rate 2 the 90 ms recording takes 45 ms; each sample at its due time, never early
    offsets = [(w - seen[0][1]) / MS for _, w in seen]
    for (log_ns, _), off in zip(seen, offsets, strict=False):
        assert off >= log_ns / MS / 2.0 - 0.5
    assert all(late >= 0 for late in stats.lateness_ns)


class VirtualClock:
    """A time base that moves only when the replayer sleeps: pacing checked exactly, whatever the load."""

    def __init__(self) -> None:
        self.now_ns = 10**12

    def __call__(self) -> int:
        return self.now_ns

    def sleep(self, seconds: float) -> None:
        self.now_ns += max(1, round(seconds * 1e9))


@pytest.mark.parametrize("rate", [0.5, 1.0, 3.0])
def test_each_sample_goes_out_when_the_recording_clock_says(config: ReplayConfig, rate: float) -> None:
    data = msgs([0, 20, 40, 41, 90, 1500])
    clock = VirtualClock()
    sent: list[int] = []
    start = clock()
    Replayer(lambda: iter(data), lambda m: sent.append(clock() - start) or True, rate=rate, loop=False,
             config=config, clock=clock, sleep=clock.sleep).run()
    # the recording's own clock (log time from the first sample), divided by the rate
    due = [(m.log_time_ns - data[0].log_time_ns) / rate for m in data]
    assert sent == pytest.approx(due, abs=2)


def test_as_fast_as_possible_does_not_sleep(config: ReplayConfig) -> None:
    data = msgs([i * 1000.0 for i in range(50)])  # 49 s of recording
    out: list[LoggedMessage] = []
    start = time.monotonic()
    Replayer(lambda: iter(data), lambda m: out.append(m) or True, rate=None, loop=False, config=config).run()
    assert out == data
    assert time.monotonic() - start < 10.0  # far less than 49 s: nothing slept on


def test_loop_repeats_until_stopped(config: ReplayConfig) -> None:
    data = msgs([0, 1, 2])
    out: list[LoggedMessage] = []
    r = Replayer(
        lambda: iter(data),
        lambda m: (out.append(m), len(out) >= 10 and r.stop())[0] or True,
        rate=None,
        loop=True,
        config=config,
    )
    stats = r.run()
    assert stats.stopped and stats.loops >= 4
    assert out[:9] == data * 3


def test_sink_refusals_are_counted_as_skipped(config: ReplayConfig) -> None:
    data = msgs([0, 1, 2, 3])
    stats = Replayer(
        lambda: iter(data), lambda m: m.data[0] % 2 == 0, rate=None, loop=False, config=config
    ).run()
    assert (stats.published, stats.skipped) == (2, 2)


class HoldWatch(threading.Condition):
    """The replayer's condition, telling when the replayer waits on it: it waits only while paused, so a
    wait proves it took the next sample in hand and held it back."""

    def __init__(self) -> None:
        super().__init__()
        self.held = threading.Event()

    def wait(self, timeout: float | None = None) -> bool:
        self.held.set()
        return super().wait(timeout)


def test_pause_holds_and_step_publishes_one_sample(config: ReplayConfig) -> None:
    data = msgs([0, 10, 20, 30, 40])
    out: list[LoggedMessage] = []
    lock = threading.Lock()

    def sink(m: LoggedMessage) -> bool:
        with lock:
            out.append(m)
        return True

    r = Replayer(lambda: iter(data), sink, rate=1.0, loop=False, config=config)
    watch = r.cond = HoldWatch()
    r.toggle_pause()
    worker = threading.Thread(target=r.run)
    worker.start()
    try:
        for stepped in range(3):
            assert watch.held.wait(10), "the replayer never held at the pause"
            with lock:
                assert out == data[:stepped]  # held: nothing but the samples stepped
            with r.cond:  # a hold seen from here on comes after the step
                watch.held.clear()
                r.step()
        assert watch.held.wait(10)
        with lock:
            assert out == data[:3]
        assert r.toggle_pause() is False  # resume: the rest follows
        worker.join(10.0)
        assert not worker.is_alive()
        assert out == data
    finally:
        r.stop()
        worker.join(10.0)


def test_stop_interrupts_a_long_wait(config: ReplayConfig) -> None:
    data = msgs([0, 60_000])  # a minute apart
    r = Replayer(lambda: iter(data), lambda m: True, rate=1.0, loop=False, config=config)
    worker = threading.Thread(target=r.run)
    worker.start()
    assert wait_until(lambda: r.stats.published == 1)  # the first sample is out; the second is a minute away
    r.stop()
    worker.join(10.0)
    assert not worker.is_alive()
    assert r.stats.published == 1 and r.stats.stopped


def test_bad_rate_is_refused(config: ReplayConfig) -> None:
    with pytest.raises(ReplayError, match="--rate"):
        Replayer(lambda: iter(()), lambda m: True, rate=0.0, loop=False, config=config)
