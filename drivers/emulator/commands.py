"""Commands only the emulator takes on `controller/command`, beside the contract's (`drivers/controller/
codes.py`): the pendant it has not got, the master's release of its slave's pre-loaded trajectory, and
fault injection. Codes in foldcell's range (3000xx), apart from the contract's."""

from __future__ import annotations

from drivers.controller.codes import MOTION_COMMANDS, Command, Readable


class EmulatorCommand(Readable):
    # the pendant's actions, which the emulator has no pendant for: TEACH/PLAY mode and remote mode
    PENDANT_TEACH = 300040
    PENDANT_PLAY = 300041
    PENDANT_REMOTE_ON = 300042
    PENDANT_REMOTE_OFF = 300043
    # master -> slave: start the pre-loaded trajectory (values: (trajectory id,)) on the tick of the
    # command's header stamp (the synchronous start; drivers/emulator/master.py)
    RELEASE = 300050
    # fault injection, off by default
    FAULT_DROP_SLAVE_LINK_ON = 300100
    FAULT_DROP_SLAVE_LINK_OFF = 300101
    FAULT_FREEZE_FEEDBACK_ON = 300102
    FAULT_FREEZE_FEEDBACK_OFF = 300103
    FAULT_ALARM_ON = 300104  # raise an injected alarm (cleared by RESET_ALARM or FAULT_ALARM_OFF)
    FAULT_ALARM_OFF = 300105
    FAULT_REPLY_LATENCY_ON = 300106  # values: (latency s, jitter s)
    FAULT_REPLY_LATENCY_OFF = 300107
    FAULT_SLOW_LOOP_ON = 300108  # values: (factor >= 1): the wrapper's loop period is multiplied by it
    FAULT_SLOW_LOOP_OFF = 300109


AnyCommand = Command | EmulatorCommand

# The lease guards every emulator command too: a frozen feedback or teach mode under a running cell is
# an attack, not a test, and a release is the master's alone.
LEASED_COMMANDS = MOTION_COMMANDS | frozenset(EmulatorCommand)


def command_of(code: int) -> AnyCommand:
    """The command a code names, the contract's or the emulator's; ValueError for neither."""
    try:
        return Command(code)
    except ValueError:
        return EmulatorCommand(code)
