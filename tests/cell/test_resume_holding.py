"""A cell daemon killed (kill -9) with a gripper closed on the cloth: restarted, it knows what the gripper
holds, and `resume` lays the cloth down where its fold puts it, lets go, checks the fold by the camera
and finishes the garment. What the grippers did is read on the wire (the controller's
`controller/gripper/*`), how the garment ended in the simulated world's ground truth; not from the job
file."""

from __future__ import annotations

import threading

import pytest

from drivers.robot.table import default_table_config
from statemachine.machine import WORK_STATES
from tests.cell.test_e2e import Cell
from tests.cell.test_recovery import MIN_FINAL_IOU, Story

pytestmark = pytest.mark.slow

TABLE_TOP_Z = default_table_config().height


class Grippers:
    """The controller's gripper states as they arrive at an observer: (arm, closed, TCP z above the
    table top) in order."""

    def __init__(self, cell: Cell):
        self.changed = threading.Condition()
        self.heard: list[tuple[str, bool, float]] = []
        cell.wire.subscribe("controller/gripper/*", self._on)

    def _on(self, _k, msg, _r) -> None:
        with self.changed:
            self.heard.append((msg.arm, bool(msg.closed), msg.tcp_pose.position.z - TABLE_TOP_Z))
            self.changed.notify_all()

    def wait(self, predicate, timeout: float, since: int = 0) -> tuple[int, tuple[str, bool, float]]:
        """The first state heard (from index `since` on) that satisfies `predicate`, and its index."""
        with self.changed:
            assert self.changed.wait_for(
                lambda: any(predicate(h) for h in self.heard[since:]), timeout), self.heard[since:][-5:]
            index = next(i for i in range(since, len(self.heard)) if predicate(self.heard[i]))
            return index, self.heard[index]

    def count(self) -> int:
        with self.changed:
            return len(self.heard)


# (fold, how high above the table the closed gripper's TCP is when the cell dies): at the grasp in the
# first fold, its cloth not lifted yet; and on its way up, mid-carry, in the second
@pytest.mark.parametrize(("fold_index", "lifted"), [(1, 0.0), (2, 0.02)])
def test_a_cell_killed_with_cloth_in_a_gripper_lays_it_down_on_resume_and_finishes(
        spawn, endpoint, tmp_path, fold_index, lifted):
    cell = Cell(spawn, endpoint, tmp_path)
    try:
        story = Story(cell)
        grippers = Grippers(cell)
        assert cell.command("fold", "towel").accepted
        cell.wait_state({"grasping"}, 120, fold_index=fold_index)
        _, (arm, _, height) = grippers.wait(lambda h: h[1] and h[2] >= lifted, 60, grippers.count())
        cell.kill("cell")
        # the robot stopped with the gripper closed: the controller says so again at rest
        after_kill = grippers.count()
        grippers.wait(lambda h: h[0] == arm, 10, after_kill)
        assert all(closed for a, closed, _ in grippers.heard[after_kill:] if a == arm), \
            f"gripper {arm} opened before the cell died (killed too late, at {height:.3f} m)"
        cell.restart("cell")
        _, msg = cell.wait_state({"paused", "idle", "fault"}, 30)
        assert msg.state == "paused", (msg.state, msg.reason)
        assert f"gripper {arm} held the cloth" in msg.reason, msg.reason
        reply = cell.command("reset")
        assert reply.accepted and f"gripper {arm} holds the cloth" in reply.text, reply.text
        reply = cell.command("resume")
        assert reply.accepted, reply.text
        cell.wait_state(set(WORK_STATES), 30)   # at work again: the states before are forgotten
        # the gripper lets go of the cloth low over the table, not up in the air where it stopped
        _, (_, _, released_at) = grippers.wait(lambda h: h[0] == arm and not h[1], 60, after_kill)
        assert released_at < 0.03, f"gripper {arm} opened {released_at:.3f} m above the table"
        _, msg = cell.wait_state({"done", "failed", "fault"}, 180)
        assert msg.state == "done", msg.reason
        # the fold its grippers were making checked, not redone
        assert story.folds_reported(2) == [1, 2], story.reports
        assert story.final_iou() >= MIN_FINAL_IOU
    finally:
        cell.close()
