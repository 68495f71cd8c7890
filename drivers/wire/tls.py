"""TLS sockets under the cell's CA for the links that are not Zenoh (MotoROS' TCP ports under
--security): each end shows its role's certificate and checks the other's against the CA."""

from __future__ import annotations

import ssl
from pathlib import Path

import zenoh

from drivers.wire.security import SecurityConfig, identity, load_security_config


def server_context(directory: str | Path, role: str, source: str = "--security") -> ssl.SSLContext:
    """A server showing `role`'s certificate that requires a client certificate signed by the CA."""
    files = identity(directory, role, source)
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    context.verify_mode = ssl.CERT_REQUIRED
    context.load_verify_locations(files.ca)
    context.load_cert_chain(files.certificate, files.key)
    return context


def client_context(directory: str | Path, role: str, source: str = "--security") -> ssl.SSLContext:
    """A client showing `role`'s certificate that accepts a server only with a certificate of the CA
    valid for the host name it connects to."""
    files = identity(directory, role, source)
    context = ssl.create_default_context(cafile=str(files.ca))  # the cell's CA only, host names checked
    context.load_cert_chain(files.certificate, files.key)
    return context


def roles_calling(key: str, config: SecurityConfig | None = None) -> frozenset[str]:
    """The roles whose `calls` (config/security.yaml) include `key`, read as the router's access control
    reads them (Zenoh key expressions)."""
    config = config or load_security_config()
    return frozenset(role for role, rights in config.roles.items()
                     if any(zenoh.KeyExpr(call).includes(key) for call in rights.calls))
