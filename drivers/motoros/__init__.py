"""MotoROS 1 ("simple message" over TCP): the protocol of a real DX100, spoken by the emulator and
by the cell.

- `messages`: pure encode/decode of every message, both dialects (upstream MotoROS 1, CloPeMa), a framer.
- `config`: `config/motoros.yaml`.
- `server`: `MotorosServer`, motion, state and IO ports in front of the emulator's `ControllerCore`.
- `client`: `MotorosController`, the cell's `Controller` interface over MotoROS (a real DX100 or the
  emulator's server).
"""
