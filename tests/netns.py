"""A network namespace joined to this one by a veth pair, to run a process on the far side of a link
that a test can cut (packets silently lost, as in a real partition) and heal."""

from __future__ import annotations

import os
import shutil
import subprocess
import uuid


class NetNamespace:
    """`ip netns` NAME with a veth pair: this side `near` (10.N.M.1), the namespace's side `far`
    (10.N.M.2). `prefix()` runs a command inside; `cut()` / `heal()` take the far end down and up."""

    def __init__(self) -> None:
        tag = uuid.uuid4().hex[:6]
        self.name = f"fc{tag}"
        self.near_dev, self.far_dev = f"fc{tag}a", f"fc{tag}b"
        octets = int(tag[:4], 16)
        self.subnet = f"10.{100 + octets % 100}.{octets // 100 % 250}"
        self.near, self.far = f"{self.subnet}.1", f"{self.subnet}.2"
        self.made = False

    @staticmethod
    def unavailable() -> str:
        """Why namespaces cannot be made here ('' when they can)."""
        if shutil.which("ip") is None:
            return "the `ip` tool (iproute2) is not installed"
        if os.geteuid() != 0:
            return "making network namespaces needs root"
        probe = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True)
        return "" if probe.returncode == 0 else f"`ip netns` fails: {probe.stderr.strip()}"

    def _ip(self, *words: str, inside: bool = False) -> None:
        argv = ["ip", "netns", "exec", self.name, "ip", *words] if inside else ["ip", *words]
        subprocess.run(argv, check=True, capture_output=True, text=True)

    def __enter__(self) -> NetNamespace:
        self._ip("netns", "add", self.name)
        self.made = True
        self._ip("link", "add", self.near_dev, "type", "veth", "peer", "name", self.far_dev)
        self._ip("link", "set", self.far_dev, "netns", self.name)
        self._ip("addr", "add", f"{self.near}/24", "dev", self.near_dev)
        self._ip("link", "set", self.near_dev, "up")
        self._ip("addr", "add", f"{self.far}/24", "dev", self.far_dev, inside=True)
        self._ip("link", "set", self.far_dev, "up", inside=True)
        self._ip("link", "set", "lo", "up", inside=True)
        return self

    def prefix(self) -> list[str]:
        return ["ip", "netns", "exec", self.name]

    def cut(self) -> None:
        self._ip("link", "set", self.far_dev, "down", inside=True)

    def heal(self) -> None:
        self._ip("link", "set", self.far_dev, "up", inside=True)

    def __exit__(self, *exc: object) -> None:
        if self.made:
            subprocess.run(["ip", "netns", "del", self.name], capture_output=True)
            subprocess.run(["ip", "link", "del", self.near_dev], capture_output=True)
