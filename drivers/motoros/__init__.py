"""MotoROS 1 ("simple message" over TCP): the protocol of a real DX100, spoken by the emulator.

- `messages`: pure encode/decode of every message, both dialects (upstream MotoROS 1, CloPeMa), a framer.
- `config`: `config/motoros.yaml`.
- `server`: `MotorosServer`, motion and state ports in front of the emulator's `ControllerCore`.
"""
