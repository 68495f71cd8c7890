"""A commander's credential on the controller's queryables: its name (`alive/<process>`) and a signature.

No secret travels. Each commander makes an Ed25519 key pair per session; every request it sends carries,
in the query attachment, its name, a sequence number that grows with every request, its public key and
a signature over (name, sequence, key expression, SHA-256 of the payload). The controller pins the public
key that acquires the lease and obeys, under the holder's name, only requests that key signed, each
sequence number once (`ReplayWindow`). A request caught on the way (a stranger serving the same key on an
open cell receives it whole) is worth nothing: its signature covers that one request, which the
controller has already seen. The slave pins its master's key the same way, on first contact.
"""

from __future__ import annotations

import hashlib
import itertools
import threading
from dataclasses import dataclass

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey
from cryptography.hazmat.primitives.serialization import Encoding, PublicFormat

SEPARATOR = "\n"
MAX_ATTACHMENT = 512  # bytes: a name, a number, a hex key and a hex signature fit with room to spare
PUBLIC_KEY_BYTES = 32
SIGNATURE_BYTES = 64
DOMAIN = b"foldcell-request-v1"   # signatures made for this purpose only


def signed_bytes(client: str, sequence: int, key_expr: str, payload: bytes) -> bytes:
    """What a request's signature covers."""
    return b"\0".join((DOMAIN, client.encode(), str(sequence).encode(), key_expr.encode(),
                       hashlib.sha256(payload).digest()))


class Signer:
    """A commander's key pair for one session; `attachment` signs one request (thread-safe)."""

    def __init__(self, client: str):
        self.client = client   # the sender's liveliness token, `alive/<process>`
        self._private = Ed25519PrivateKey.generate()
        self.public_key = self._private.public_key().public_bytes(Encoding.Raw, PublicFormat.Raw)
        self._sequence = itertools.count(1)
        self._lock = threading.Lock()

    def attachment(self, key_expr: str, payload: bytes) -> bytes:
        """The credential for a request of `payload` on the full key `key_expr`."""
        with self._lock:
            sequence = next(self._sequence)
        signature = self._private.sign(signed_bytes(self.client, sequence, key_expr, payload))
        return SEPARATOR.join((self.client, str(sequence), self.public_key.hex(), signature.hex())).encode()


@dataclass(frozen=True)
class Credential:
    """The credential a request carries; the empty one when it carries none that reads."""

    client: str = ""
    sequence: int = 0
    public_key: bytes = b""
    signature: bytes = b""

    @classmethod
    def from_attachment(cls, data: bytes) -> Credential:
        """The credential in a query attachment; a missing, oversized or undecodable one is empty (the
        request is then judged as a stranger's, never rejected for its attachment alone)."""
        if not data or len(data) > MAX_ATTACHMENT:
            return cls()
        parts = data.decode("utf-8", "replace").split(SEPARATOR)
        if len(parts) != 4:
            return cls(parts[0])
        client, sequence, public_key, signature = parts
        try:
            key, sig, seq = bytes.fromhex(public_key), bytes.fromhex(signature), int(sequence)
        except ValueError:
            return cls(client)
        if len(key) != PUBLIC_KEY_BYTES or len(sig) != SIGNATURE_BYTES or seq <= 0:
            return cls(client)
        return cls(client, seq, key, sig)

    def signed_by(self, public_key: bytes, key_expr: str, payload: bytes) -> bool:
        """True when `public_key` is the one this credential names and signed this request."""
        if not public_key or public_key != self.public_key:
            return False
        try:
            Ed25519PublicKey.from_public_bytes(public_key).verify(
                self.signature, signed_bytes(self.client, self.sequence, key_expr, payload))
        except (InvalidSignature, ValueError):
            return False
        return True


class ReplayWindow:
    """The sequence numbers one key has used: each is admitted once, and none `SIZE` or more below the
    highest seen. A window, not a strict order: a commander's renewals and commands leave on threads of
    their own and reach the controller's lanes in any order."""

    SIZE = 1024

    def __init__(self) -> None:
        self.highest = 0
        self.seen: set[int] = set()

    def fresh(self, sequence: int) -> bool:
        return sequence > self.highest - self.SIZE and sequence not in self.seen

    def admit(self, sequence: int) -> bool:
        """Take `sequence`; False (and nothing taken) when it was used or is too old."""
        if not self.fresh(sequence):
            return False
        self.seen.add(sequence)
        self.highest = max(self.highest, sequence)
        if len(self.seen) > 2 * self.SIZE:
            self.seen = {s for s in self.seen if s > self.highest - self.SIZE}
        return True


class PinnedKey:
    """The one key a controller obeys under a name (the lease holder's; the slave's master's), pinned at
    its first request, with the sequence numbers it has used."""

    def __init__(self, client: str, public_key: bytes):
        self.client = client
        self.public_key = public_key
        self.window = ReplayWindow()

    def vouches(self, credential: Credential, key_expr: str, payload: bytes) -> bool:
        """This key signed the request, under its name, with a sequence not used yet (nothing taken)."""
        return credential.client == self.client and self.window.fresh(credential.sequence) \
            and credential.signed_by(self.public_key, key_expr, payload)

    def admits(self, credential: Credential, key_expr: str, payload: bytes) -> bool:
        """`vouches`, and its sequence number is taken: the same request is refused a second time."""
        return self.vouches(credential, key_expr, payload) and self.window.admit(credential.sequence)
