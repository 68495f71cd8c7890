"""The cell's locked-down wire: a CA of its own, one certificate per role, Zenoh mutual TLS and
access control by the role in each peer's certificate (config/security.yaml says who may do what).

`create_security(DIR)` writes one directory per role, `DIR/<role>/` holding `ca.pem`, `<role>.pem`
and `<role>.key`, and the CA's own key apart in `DIR/ca-private/`: each machine gets only the
directories of the roles it runs, so a process can read no other role's key. A process started
with `--security DIR/<role>` (or FOLDCELL_SECURITY) in role R reaches its `tcp/` endpoints over
TLS on the same host and port and shows R's certificate. The processes meet at a
Zenoh router (role `router`, `foldcell router`) that serves those endpoints, accepts only
certificates the CA signed and drops what a client sends beyond its role's rights; every other
process is a Zenoh client that talks to nothing but the router.

Why a router and not the open cell's peer mesh: Zenoh's ACL judges each message by the link it
arrives on, and a link that gossip scouting opens after a peer's start can miss the declarations
exchanged on it (Zenoh 1.10: a peer linked that way to a controller saw neither its token nor its
queryable in about half of the tries), while a client linked to a router at its start is reliable.
"""

from __future__ import annotations

import datetime
import ipaddress
import json
import os
import re
import socket
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from drivers.common.configfile import ConfigError, config_dir, load_yaml

ENV_SECURITY = "FOLDCELL_SECURITY"
CA_NAME = "ca"
CA_PRIVATE = "ca-private"   # the CA's key, which signs any role: kept off the cell's machines
ROUTER_ROLE = "router"
LIVE, REPLAY = "live", "replay"   # the cells a role's rights hold in (security.yaml `cells`)
REPLAY_SUFFIX = "-replay"         # a replay's own cell id: `<cell>-replay`
# Zenoh's message kinds (its ACL names) a peer may send to everyone: reading is open to every role
READ_MESSAGES = ("declare_subscriber", "liveliness_query", "declare_liveliness_subscriber")
EVERY_MESSAGE = ("put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
                 "liveliness_token", "liveliness_query", "declare_liveliness_subscriber")


class SecurityError(Exception):
    """A security directory that cannot be used, named with the reason."""


@dataclass(frozen=True)
class Rights:
    """What one role may send (keys relative to foldcell/<cell>/), and in which cells: the live one
    the router serves, or only replay cells (`<id>-replay`)."""

    publishes: tuple[str, ...]
    serves: tuple[str, ...]
    calls: tuple[str, ...]
    alive: tuple[str, ...]
    cells: str = LIVE


@dataclass(frozen=True)
class SecurityConfig:
    certificate_days: int
    roles: dict[str, Rights]


def load_security_config(path: str | Path | None = None) -> SecurityConfig:
    path = Path(path) if path else config_dir() / "security.yaml"
    f = load_yaml(path)
    f.reject_unknown({"certificate_days", "roles"})
    roles_field = f.sub("roles")
    roles = {}
    names = roles_field.keys()
    for role in names:
        item = roles_field.sub(role)
        item.reject_unknown({"publishes", "serves", "calls", "alive", "cells"})
        if role in (CA_NAME, CA_PRIVATE) or not role.replace("-", "").isalnum():
            raise roles_field.error(role, f"a role name is letters, digits and '-', and not "
                                          f"{CA_NAME!r} or {CA_PRIVATE!r}")
        cells = item.str("cells", LIVE, choices=(LIVE, REPLAY))
        roles[role] = Rights(item.strs("publishes"), item.strs("serves"), item.strs("calls"),
                             item.strs("alive"), cells)
    if not roles:
        raise ConfigError(path, "roles", "needs at least one role")
    return SecurityConfig(f.int("certificate_days", min=1), roles)


# --------------------------------------------------------------------- certificates
def _new_key() -> ec.EllipticCurvePrivateKey:
    return ec.generate_private_key(ec.SECP256R1())


def _write_key(key: ec.EllipticCurvePrivateKey, path: Path) -> None:
    data = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())
    descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(descriptor, "wb") as out:
        out.write(data)


# a DNS host name: dot-separated labels of letters, digits and inner hyphens (RFC 1123), and
# underscores, which some machines' own names carry
_HOST_NAME = re.compile(r"(?!-)[A-Za-z0-9_-]{1,63}(?<!-)(\.(?!-)[A-Za-z0-9_-]{1,63}(?<!-))*\.?")


def check_host(host: str) -> None:
    """A name a certificate can be valid for: an IP address or a DNS host name."""
    try:
        ipaddress.ip_address(host)
        return
    except ValueError:
        pass
    if len(host) > 253 or not _HOST_NAME.fullmatch(host):
        raise SecurityError(f"host {host!r}: not an IP address or a host name (dot-separated labels of "
                            "letters, digits, underscores and inner hyphens)")


def _names(hosts: Iterable[str]) -> list[x509.GeneralName]:
    names: list[x509.GeneralName] = []
    for host in hosts:
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            names.append(x509.DNSName(host))
    return names


def default_hosts() -> tuple[str, ...]:
    """Names a certificate is valid for when none are given: this machine and loopback."""
    return tuple(dict.fromkeys(("localhost", "127.0.0.1", "::1", socket.gethostname())))


def _private_directory(path: Path) -> Path:
    path.mkdir(mode=0o700, parents=True, exist_ok=True)
    path.chmod(0o700)   # mkdir's mode is cut by the umask, and an existing directory keeps its own
    return path


def create_security(directory: str | Path, hosts: Iterable[str] | None = None, *,
                    config: SecurityConfig | None = None, force: bool = False) -> list[Path]:
    """Write a new CA into `directory`/ca-private and, for every role, `directory`/<role>/ with the
    role's key and certificate (common name = role, valid for `hosts`: DNS names or IP addresses the
    processes listen on) and the CA's certificate. Returns the files written."""
    config = config or load_security_config()
    directory = Path(directory)
    hosts = tuple(hosts) if hosts else default_hosts()
    if not hosts:
        raise SecurityError("hosts: give at least one host name or address")
    for host in hosts:
        check_host(host)
    if directory.exists() and not directory.is_dir():
        raise SecurityError(f"{directory}: exists and is not a directory")
    if (directory / CA_PRIVATE).exists() and not force:
        raise SecurityError(f"{directory}: already holds a CA ({CA_PRIVATE}/); --force replaces it "
                            "(and every certificate made from it)")
    now = datetime.datetime.now(datetime.timezone.utc)
    start, end = now - datetime.timedelta(minutes=5), now + datetime.timedelta(days=config.certificate_days)
    ca_key = _new_key()
    ca_name = x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "foldcell"),
                         x509.NameAttribute(NameOID.COMMON_NAME, "foldcell cell CA")])
    ca = (x509.CertificateBuilder().subject_name(ca_name).issuer_name(ca_name)
          .public_key(ca_key.public_key()).serial_number(x509.random_serial_number())
          .not_valid_before(start).not_valid_after(end)
          .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
          .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                       content_commitment=False, key_encipherment=False,
                                       data_encipherment=False, key_agreement=False,
                                       encipher_only=False, decipher_only=False), critical=True)
          .add_extension(x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key()), critical=False)
          .sign(ca_key, hashes.SHA256()))
    ca_pem = ca.public_bytes(serialization.Encoding.PEM)
    private = _private_directory(directory / CA_PRIVATE)
    written = [private / f"{CA_NAME}.pem", private / f"{CA_NAME}.key"]
    written[0].write_bytes(ca_pem)
    _write_key(ca_key, written[1])
    for role in config.roles:
        key = _new_key()
        certificate = (
            x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "foldcell"),
                                     x509.NameAttribute(NameOID.COMMON_NAME, role)]))
            .issuer_name(ca_name).public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(start).not_valid_after(end)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.SubjectAlternativeName(_names(hosts)), critical=False)
            # every peer both listens and connects, so each certificate serves both ends of a link
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                  ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()),
                           critical=False)
            .sign(ca_key, hashes.SHA256()))
        own = _private_directory(directory / role)
        files = own / f"{CA_NAME}.pem", own / f"{role}.pem", own / f"{role}.key"
        files[0].write_bytes(ca_pem)
        files[1].write_bytes(certificate.public_bytes(serialization.Encoding.PEM))
        _write_key(key, files[2])
        written += files
    return written


@dataclass(frozen=True)
class Identity:
    """One role's files in its security directory, checked."""

    role: str
    ca: Path
    certificate: Path
    key: Path


def identity(directory: str | Path, role: str, source: str = "--security") -> Identity:
    """The role's certificate in its own directory (`security init`'s DIR/<role>), checked: present,
    signed by the directory's CA, for this role, valid now, and alone with its key: a directory
    holding other keys (the top of `security init`, or a CA's) is refused, as the process could read
    them. `source` names the flag or variable that gave the directory (in messages)."""
    directory = Path(directory)
    if not directory.is_dir():
        raise SecurityError(f"{source}: {directory} is not a directory (make one with "
                            "`foldcell security init DIR`, then give each process DIR/<role>)")
    paths = Identity(role, directory / f"{CA_NAME}.pem", directory / f"{role}.pem", directory / f"{role}.key")
    if (directory / role).is_dir() and not paths.certificate.exists():
        raise SecurityError(f"{source}: {directory} holds every role's directory; give this process "
                            f"its own, {directory / role}, so it cannot read the others' keys")
    others = sorted(p.name for p in directory.glob("*.key") if p != paths.key)
    if others and not paths.key.exists():
        raise SecurityError(f"{source}: {directory} is not the directory of role {role!r}, which this "
                            f"command runs as (it holds {', '.join(others)}): give it DIR/{role}")
    if others:
        raise SecurityError(f"{source}: {directory} holds other keys than {paths.key.name} "
                            f"({', '.join(others)}); give the process a directory with its own key only "
                            "(`foldcell security init DIR` makes DIR/<role>)")
    for path in (paths.ca, paths.certificate, paths.key):
        if not path.is_file():
            raise SecurityError(f"{source}: {path} is missing (the role {role!r} needs it)")
    if paths.key.stat().st_mode & 0o077:
        raise SecurityError(f"{source}: {paths.key} can be read by others than its owner "
                            f"(mode {paths.key.stat().st_mode & 0o777:o}): chmod 600 it")
    try:
        ca = x509.load_pem_x509_certificate(paths.ca.read_bytes())
        certificate = x509.load_pem_x509_certificate(paths.certificate.read_bytes())
        serialization.load_pem_private_key(paths.key.read_bytes(), password=None)
    except ValueError as exc:
        raise SecurityError(f"{source}: {directory}: not a PEM certificate or key: {exc}") from exc
    try:
        certificate.verify_directly_issued_by(ca)
    except (InvalidSignature, ValueError, TypeError) as exc:
        raise SecurityError(f"{source}: {paths.certificate} was not signed by {paths.ca}") from exc
    names = certificate.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    if not names or names[0].value != role:
        raise SecurityError(f"{source}: {paths.certificate} is not the certificate of role {role!r}")
    now = datetime.datetime.now(datetime.timezone.utc)
    if not certificate.not_valid_before_utc <= now <= certificate.not_valid_after_utc:
        raise SecurityError(f"{source}: {paths.certificate} is not valid now (valid "
                            f"{certificate.not_valid_before_utc:%Y-%m-%d} to "
                            f"{certificate.not_valid_after_utc:%Y-%m-%d})")
    return paths


def role_directory(top: str | Path, role: str) -> Path:
    """`role`'s directory in the top directory of `security init`, for a command that starts every
    role (`foldcell demo`)."""
    top = Path(top)
    if not (top / CA_PRIVATE).is_dir() and not (top / ROUTER_ROLE).is_dir():
        raise SecurityError(f"--security: {top} is not the top directory of `foldcell security init` "
                            "(one directory per role); this command starts every role and needs it")
    return top / role


def replay_cell_id(cell_id: str) -> str:
    """The cell id a replay of `cell_id` goes to by default: the only cells a player may publish in."""
    return cell_id if cell_id.endswith(REPLAY_SUFFIX) else cell_id + REPLAY_SUFFIX


# --------------------------------------------------------------------- Zenoh configuration
def tls_endpoint(endpoint: str) -> str:
    """`tcp/H:P` served and reached over TLS on the same host and port; other protocols as given."""
    return "tls/" + endpoint.removeprefix("tcp/") if endpoint.startswith("tcp/") else endpoint


def router_access_control(config: SecurityConfig, cell_id: str) -> dict:
    """The router's ACL: each role's rights over what it sends (ingress), in the router's own cell or,
    for a role of replay cells, in `<any id>-replay` only; everything the router forwards passes."""
    if cell_id.endswith(REPLAY_SUFFIX):
        raise SecurityError(f"--cell: {cell_id!r} ends in {REPLAY_SUFFIX!r}, which names a replay's "
                            "cell; a secured cell needs another id")
    cells = {LIVE: cell_id, REPLAY: f"$*{REPLAY_SUFFIX}"}

    rules: list[dict] = [
        {"id": "send", "permission": "allow", "flows": ["egress"], "messages": list(EVERY_MESSAGE),
         "key_exprs": ["**"]},
        {"id": "read", "permission": "allow", "flows": ["ingress"], "messages": list(READ_MESSAGES),
         "key_exprs": ["**"]},
    ]
    subjects, policies = [], []
    for role, rights in config.roles.items():
        own = []
        for kind, messages, relative in (("publishes", ["put", "delete"], rights.publishes),
                                         ("serves", ["declare_queryable", "reply"], rights.serves),
                                         ("calls", ["query"], rights.calls),
                                         ("alive", ["liveliness_token"], rights.alive)):
            if relative:
                rules.append({"id": f"{role} {kind}", "permission": "allow", "flows": ["ingress"],
                              "messages": messages,
                              "key_exprs": [f"foldcell/{cells[rights.cells]}/{key}" for key in relative]})
                own.append(f"{role} {kind}")
        subjects.append({"id": role, "cert_common_names": [role]})
        policies.append({"rules": ["send", "read", *own], "subjects": [role]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def client_access_control() -> dict:
    """A client's ACL: it exchanges messages with a peer holding the router's certificate only."""
    return {"enabled": True, "default_permission": "deny",
            "rules": [{"id": "router", "permission": "allow", "flows": ["ingress", "egress"],
                       "messages": list(EVERY_MESSAGE), "key_exprs": ["**"]}],
            "subjects": [{"id": ROUTER_ROLE, "cert_common_names": [ROUTER_ROLE]}],
            "policies": [{"rules": ["router"], "subjects": [ROUTER_ROLE]}]}


def secure_zenoh_settings(directory: str | Path, role: str, cell_id: str,
                          config: SecurityConfig | None = None, source: str = "--security") -> dict[str, str]:
    """Zenoh config insertions (path -> JSON5) that make a process of `role` secure: the router
    (mode router, the roles' ACL) or a client of it."""
    config = config or load_security_config()
    if role not in config.roles:
        raise SecurityError(f"role: {role!r} is not one of config/security.yaml's roles "
                            f"({', '.join(config.roles)})")
    files = identity(directory, role, source)
    tls = {
        "root_ca_certificate": str(files.ca),
        "enable_mtls": True,
        "listen_certificate": str(files.certificate),
        "listen_private_key": str(files.key),
        "connect_certificate": str(files.certificate),
        "connect_private_key": str(files.key),
        "verify_name_on_connect": True,
    }
    router = role == ROUTER_ROLE
    acl = router_access_control(config, cell_id) if router else client_access_control()
    return {"mode": json.dumps("router" if router else "client"), "transport/link/tls": json.dumps(tls),
            "access_control": json.dumps(acl)}
