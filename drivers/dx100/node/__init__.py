"""The DX100 emulator over Zenoh: `foldcell controller serve --role master|slave|both`.

- `codec`: emulator dataclasses <-> wire messages (`ControllerStatus`, `JointState`, `MotionReply`...).
- `clock`: robot time shared by master and slave processes, with `--time-scale`.
- `server`: `ControllerNode`, the fixed-period loop, queryables, master/slave forwarding, lease watch.
"""
