"""The DX100/MotoROS-style controller emulator core: pure, driven by explicit robot time.

- `codes`: MotoROS result codes, subcodes, commands (+ foldcell's), alarms, `Reply`.
- `config`: `config/controller.yaml` -> `ControllerConfig`.
- `interpolation`: MotoROS' cubic Hermite between points, exact per-segment bounds.
- `acceptance`: `check_trajectory` (stateless rules) and `check_ready` (readiness).
- `motion`: a trajectory prepared for per-tick evaluation; ruckig point-to-point planning.
- `core`: `ControllerCore`, one DX100 (master, slave or both) stepped one 4 ms tick at a time.
- `split`: master/slave split of a trajectory, merged feedback and status, link-loss monitor.
- `local`: `LocalController`, the `drivers.controller.interface.Controller` interface over an in-process core.
- `trajfile`: trajectory YAML files for the CLI.
"""
