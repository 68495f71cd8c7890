"""A partition between the cell and its controller (`partition_run`): both sides notice, stop and say
why; after the heal the operator's reset and a new fold finish a garment, with no process restarted."""

from __future__ import annotations

import pytest

from tests.cell.partition_run import run_partition
from tests.netns import NetNamespace


@pytest.fixture
def namespace():
    why = NetNamespace.unavailable()
    if why:
        pytest.skip(f"no network namespace for the partition test: {why}")
    with NetNamespace() as ns:
        yield ns


@pytest.mark.timeout(300)
def test_a_partition_mid_fold_stops_both_sides_and_the_cell_recovers_after_the_heal(namespace, tmp_path):
    result = run_partition(namespace, tmp_path)
    assert "controller" in result.fault_reason, result   # not the camera, which is still there
    # within the 1.0 s the design allows (Zenoh's link lease is 0.4 s; `make bench faults` measures it),
    # also for the controller, which once took 10.5 s: a dead link's 10 s linger froze Zenoh's two
    # receiving threads (config/cell.yaml zenoh.runtime)
    assert result.cell_fault_s <= 1.0 and result.controller_stop_s <= 1.0, result
    assert result.after_heal == "done", result.after_heal_reason
