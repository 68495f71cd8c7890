"""The running processes' queryables under property-based fuzzing (tests/wire/live_fuzz.py): every case
is answered, no process dies, the joint stream goes on. `make bench` (`fuzz`) runs many more."""

from __future__ import annotations

import pytest

from tests.wire.live_fuzz import ENDPOINTS, Tally, fuzz_endpoint, live_cell

EXAMPLES = 25  # per endpoint, derandomized: the same cases every run


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    with live_cell(tmp_path_factory.mktemp("fuzz")) as running:
        yield running


@pytest.mark.parametrize("key", ENDPOINTS)
def test_every_case_is_answered_and_every_process_lives(cell, key):
    tally = Tally()
    fuzz_endpoint(cell, key, EXAMPLES, True, tally)
    assert not tally.unanswered, tally.unanswered[:3]
    assert sum(tally.outcomes[key].values()) >= EXAMPLES // 2, tally.outcomes   # hypothesis ran them
    assert tally.outcomes[key]["refused"] > 0, tally.outcomes   # the malformed ones were refused
    assert not cell.dead(), {name: cell.procs[name].stderr()[-1500:] for name in cell.dead()}
    assert cell.joint_states_flow(), "the joint stream stopped"
