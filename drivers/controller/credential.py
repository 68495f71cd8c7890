"""A commander's credential on the controller's queryables: its name (`alive/<process>`) and a secret.

The secret is random per session and travels only in query attachments. A query reaches the queryables
that serve its key and nobody else, so no reader on the network learns it. The controller grants the
control lease to the name and the secret together; a request that names the holder without its secret
is a stranger's (the lease cannot be taken by writing another process's name). The slave likewise pins
its master's secret. With `--security` the router's access control keeps strangers off these keys too.
"""

from __future__ import annotations

import secrets
from dataclasses import dataclass

SEPARATOR = "\n"
SECRET_BYTES = 16
MAX_ATTACHMENT = 512  # bytes: a name and a hex secret fit many times over


@dataclass(frozen=True)
class Credential:
    client: str  # the sender's liveliness token, `alive/<process>`
    secret: str  # hex; empty when the sender gave none

    @classmethod
    def new(cls, client: str) -> Credential:
        return cls(client, secrets.token_hex(SECRET_BYTES))

    def attachment(self) -> bytes:
        return f"{self.client}{SEPARATOR}{self.secret}".encode()

    @classmethod
    def from_attachment(cls, data: bytes) -> Credential:
        """The credential in a query attachment; a missing, oversized or undecodable one has no secret
        (the request is then judged as a stranger's, never rejected for its attachment alone)."""
        if not data or len(data) > MAX_ATTACHMENT:
            return cls("", "")
        text = data.decode("utf-8", "replace")
        client, _, secret = text.partition(SEPARATOR)
        return cls(client, secret)

    def proves(self, secret: str) -> bool:
        """True when this credential carries `secret` (compared in constant time)."""
        return bool(secret) and secrets.compare_digest(self.secret.encode(), secret.encode())
