"""How a step of the cell's work loop ends when it does not succeed."""

from __future__ import annotations


class StepFailed(Exception):
    """The step did not do its job; `retryable`: the state machine may try the fold again."""

    def __init__(self, reason: str, retryable: bool = True):
        super().__init__(reason)
        self.reason = reason
        self.retryable = retryable


class StepInterrupted(Exception):
    """The robot was stopped under the step (e-stop, hold, the operator): the machine already knows."""


class CameraFault(Exception):
    """The camera did not deliver an image in time: the cell faults."""
