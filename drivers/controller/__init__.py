"""The controller contract that the planner, the cell, the clients and every controller agree on.

- `interface`: `Controller`, motion handles, status dataclasses; `errors`: the typed errors.
- `trajectory`: `JointTrajectory` and MotoROS' cubic Hermite interpolation between its points.
- `acceptance`: `check_trajectory` (the rules a trajectory must pass) and `check_ready`.
- `codes`: MotoROS result codes, subcodes, commands (+ foldcell's), alarms, `Reply`.
- `config`: `config/controller.yaml` -> `ControllerConfig`; `trajfile`: trajectory files for the CLI.
- `codec`: the contract's dataclasses <-> wire messages; `zenoh_client`: `ZenohController`.
"""
