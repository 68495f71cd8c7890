"""The monitor's command keys: a key asks for pause, resume or abort of the watched cell, a second key
confirms (anything else cancels). Pure: the caller reads the keys and sends what `on_key` returns."""

from __future__ import annotations

import threading

from .config import MonitorConfig


class CommandKeys:
    """The key state and the status line. `disabled` says why no command can be sent ("" when one can)."""

    def __init__(self, config: MonitorConfig, cell: str, disabled: str = ""):
        self.config = config
        self.cell = cell
        self.disabled = disabled
        self.pending = ""  # the command awaiting confirmation
        self.lock = threading.Lock()  # keys and replies arrive on different threads
        self.status = ""

    def help(self) -> str:
        if self.disabled:
            return f"keys off: {self.disabled}"
        keys = "  ".join(f"{key} {command}" for key, command in self.config.command_keys.items())
        return f"keys: {keys}  {self.config.quit_keys[0]} quit"

    def line(self) -> str:
        """The status line: the question, the last command's fate, or the keys."""
        with self.lock:
            return self.status or self.help()

    def quits(self, key: str) -> bool:
        """A quit key when no question is open (then it is an answer)."""
        with self.lock:
            return not self.pending and key in self.config.quit_keys

    def on_key(self, key: str) -> str:
        """The command to send now ("" for none)."""
        with self.lock:
            if self.pending:
                command, self.pending = self.pending, ""
                if key in self.config.confirm_keys:
                    self.status = f"{command} {self.cell}: sent, waiting for the reply"
                    return command
                self.status = f"{command} {self.cell}: cancelled"
                return ""
            command = self.config.command_keys.get(key, "")
            if command and self.disabled:
                self.status = f"{command}: not sent: {self.disabled}"
            elif command:
                self.pending = command
                self.status = f"{command} {self.cell}? [y/N]"
            return ""

    def on_reply(self, command: str, accepted: bool, text: str, state: str) -> None:
        with self.lock:
            if accepted:
                said = f": {text}" if text else ""
                self.status = f"{command} {self.cell}: accepted, state {state or '?'}{said}"
            else:
                self.status = f"{command} {self.cell}: REFUSED: {text or 'no reason given'}"
