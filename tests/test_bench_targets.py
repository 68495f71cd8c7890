"""`make bench` fails when a target it prints is missed, and says which."""

from __future__ import annotations

import pytest

from tests.bench import targets
from tests.bench.__main__ import main as bench_main


@pytest.fixture(autouse=True)
def fresh_results():
    saved = list(targets.RESULTS)
    targets.RESULTS.clear()
    yield
    targets.RESULTS[:] = saved


def test_a_missed_target_fails_the_run_and_is_named(capsys):
    assert targets.check("demo", "fold success rate", 90.0, ">=", 95.0, "%") is False
    assert targets.check("demo", "compute per fold", 0.2, "<=", 0.3, "s") is True
    assert bench_main(["no-such-benchmark"]) == 1
    out = capsys.readouterr().out
    assert "targets missed (1 of 2)" in out and "fold success rate 90 % (target >= 95 %)" in out


def test_targets_met_pass(capsys):
    targets.check("demo", "rate", 250.0, ">=", 245.0, "Hz")
    assert bench_main(["no-such-benchmark"]) == 0
    assert "all 1 targets met" in capsys.readouterr().out


def test_an_unknown_relation_is_refused():
    with pytest.raises(ValueError, match="relation"):
        targets.check("demo", "x", 1.0, "~", 1.0)
