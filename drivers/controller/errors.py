"""The controller's errors: one family for every controller and client, typed by the MotoROS reply."""

from __future__ import annotations

from drivers.controller.codes import Reply, Result, Subcode


class ControllerError(Exception):
    """A controller refused or failed a request. `.result`/`.subcode` are the MotoROS codes
    (`drivers.controller.codes.Result`/`Subcode`), 0 when the failure is local (timeout, lost link)."""

    def __init__(self, text: str, result: int = 0, subcode: int = 0, point: int = -1, joint: str = ""):
        self.text = text
        self.result = result
        self.subcode = subcode
        self.point = point
        self.joint = joint
        super().__init__(f"{text} (result {result}, subcode {subcode})" if result else text)


class TrajectoryRejected(ControllerError):
    """The trajectory broke an acceptance rule (INVALID); `.point` and `.joint` say where."""


class InvalidArgument(ControllerError):
    """A command's argument (arm, joint, values, code) is wrong (INVALID with BAD_ARGUMENT/COMMAND)."""


class NotReady(ControllerError):
    """The controller cannot move now (NOT_READY, BUSY or ALARM): e-stop, servo off, alarm, held..."""


class LeaseHeld(ControllerError):
    """Another session holds the control lease, or this one does not hold it."""


class ControllerTimeout(ControllerError):
    """No reply, or the motion did not finish, within the timeout."""


class ControllerGone(ControllerError):
    """The controller is not connected or its liveliness token disappeared."""


class NotConnected(ControllerGone):
    """A method was called before `connect()` or after `disconnect()`."""


def error_for_reply(reply: Reply) -> ControllerError:
    """The typed error for a failed reply."""
    fields = (reply.text, reply.result, reply.subcode, reply.point, reply.joint)
    if reply.subcode in (Subcode.LEASE_HELD, Subcode.NO_LEASE):
        return LeaseHeld(*fields)
    if reply.result == Result.INVALID and reply.subcode in (Subcode.BAD_ARGUMENT, Subcode.INVALID_COMMAND):
        return InvalidArgument(*fields)
    if reply.result == Result.INVALID:
        return TrajectoryRejected(*fields)
    if reply.result in (Result.NOT_READY, Result.BUSY, Result.ALARM):
        return NotReady(*fields)
    return ControllerError(*fields)


def raise_for_reply(reply: Reply) -> Reply:
    """The reply itself when it succeeded; otherwise raise its typed error."""
    if not reply.ok:
        raise error_for_reply(reply)
    return reply
