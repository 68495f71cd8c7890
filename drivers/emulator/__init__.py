"""The DX100/MotoROS-style controller emulator, one implementation of the `drivers.controller` contract.

- `motion`: a trajectory prepared for per-tick evaluation; the ruckig motion of MOVE_TO and JOG.
- `core`: `ControllerCore`, one DX100 (master, slave or both) stepped one 4 ms tick at a time.
- `split`: master/slave split of a trajectory, merged feedback and status, link-loss monitor.
- `local`: `LocalController`, the `drivers.controller.interface.Controller` interface over an in-process core.
- `clock`: robot time shared by the master and slave processes.
- `node`: `ControllerNode`, the emulator process (`both` or `slave`) on Zenoh; `master`: `MasterNode`.
"""
