"""Where a process meets the others: cell id, Zenoh settings and endpoints (config/cell.yaml)."""

from __future__ import annotations

import ipaddress
import json
import logging
import os
import re
import socket
import ssl
import threading
from dataclasses import dataclass, replace
from pathlib import Path

import zenoh

from drivers.common.configfile import ConfigError, config_dir, load_yaml_over
from drivers.wire import security

ENV_CELL = "FOLDCELL_CELL"
ENV_LISTEN = "FOLDCELL_LISTEN"        # comma-separated endpoints, like --listen
ENV_CONNECT = "FOLDCELL_CONNECT"
ENV_SECURITY = security.ENV_SECURITY  # a security directory, like --security
ENV_ZENOH_RUNTIME = "ZENOH_RUNTIME"   # Zenoh's own: its thread pools, read once per process
ENDPOINT = re.compile(r"^(tcp|udp|tls|quic|ws|unixsock-stream)/.+")
CELL_ID = re.compile(r"^[A-Za-z0-9_\-]+$")
MODES = ("peer", "client")   # a process's Zenoh mode (a router is `foldcell router`)
# How long an endpoint given to connect to may stay unanswered before the process says so (Zenoh
# keeps trying it): long enough for a loopback or LAN link to form, short enough to be noticed.
CONNECT_WARNING_S = 2.0
PROBE_TIMEOUT_S = 2.0    # a client that reached no router asks each endpoint itself why, this long at most
OS_ERROR = re.compile(r"([A-Za-z][A-Za-z ']*?) \(os error \d+\)")
ZENOH_SOURCE_LOCATION = re.compile(r" at \S+\.rs:\d+\.?")

log = logging.getLogger(__name__)


class EndpointError(ValueError):
    """An endpoint given to listen on (or a client's router) that the session cannot use, named with
    the flag or variable that gave it and the reason."""


@dataclass(frozen=True)
class Given:
    """An endpoint named on the command line or in the environment, and what named it."""

    endpoint: str
    source: str   # "--listen", "FOLDCELL_CONNECT", ...


@dataclass(frozen=True)
class WireSettings:
    cell_id: str
    zenoh_config_file: Path
    listen: tuple[str, ...]
    connect: tuple[str, ...]
    runs_directory: Path
    config_file: Path  # the file these came from; other rooms read their own sections of it
    security: Path | None = None   # a `foldcell security init` directory: mutual TLS and access control
    security_source: str = "--security"   # the flag or variable that gave it (in messages)
    role: str = ""                 # the process's role there (config/security.yaml)
    mode: str = ""                 # Zenoh mode over the config file's: "peer", or "client" of a router
    # The file's endpoints, and those given by flags or environment; `listen` and `connect` above are
    # what the process uses (see `with_given`).
    config_listen: tuple[str, ...] = ()
    config_connect: tuple[str, ...] = ()
    given_listen: tuple[Given, ...] = ()
    given_connect: tuple[Given, ...] = ()
    zenoh_runtime: str = ""        # Zenoh's thread pools (ZENOH_RUNTIME), unless the environment sets it

    @property
    def is_client(self) -> bool:
        """A Zenoh client (of a router): serves nothing, and needs one router to start."""
        if self.security is not None:
            return self.role != security.ROUTER_ROLE
        return self.mode == "client"

    def zenoh_endpoints(self) -> tuple[list[tuple[str, str]], list[tuple[str, str]]]:
        """(endpoint, as Zenoh gets it) to listen on and to connect to, after --mode and --security."""
        listen = [] if self.is_client else list(self.listen)   # a client reaches its router only
        connect = list(self.connect)
        if self.role == security.ROUTER_ROLE:       # it serves the endpoints; other routers it may join
            connect = [e for e in connect if e not in listen]
        return [(e, self.zenoh_form(e)) for e in listen], [(e, self.zenoh_form(e)) for e in connect]

    def zenoh_form(self, endpoint: str) -> str:
        """A secured process reaches a tcp/ endpoint over TLS on the same host and port."""
        return security.tls_endpoint(endpoint) if self.security is not None else endpoint

    def required_listen(self) -> dict[str, str]:
        """Endpoint -> source of those given to listen on that the process must bind: all but the
        meeting points (also given to connect to), which the first process to start gets."""
        return {g.endpoint: g.source for g in self.given_listen if g.endpoint not in self.connect}

    def zenoh_config(self) -> zenoh.Config:
        try:
            conf = zenoh.Config.from_file(str(self.zenoh_config_file))
        except Exception as exc:
            raise ConfigError(self.zenoh_config_file, "", f"not a valid Zenoh config: {exc}") from exc
        if self.mode:
            conf.insert_json5("mode", json.dumps(self.mode))
        if self.security is not None:
            if not self.role:
                raise security.SecurityError("this command has no role to run secured in")
            for path, value in security.secure_zenoh_settings(self.security, self.role, self.cell_id,
                                                                 source=self.security_source).items():
                conf.insert_json5(path, value)
        if self.role == security.ROUTER_ROLE:
            conf.insert_json5("mode", json.dumps("router"))
        listen, connect = self.zenoh_endpoints()
        required = self.required_listen()
        # Zenoh's per-endpoint option: a required listener that cannot be bound fails zenoh.open;
        # the others follow the config file's listen/exit_on_failure (false: go on without it).
        conf.insert_json5("listen/endpoints", json.dumps(
            [with_endpoint_option(zenoh_form, "exit_on_failure=true") if endpoint in required else zenoh_form
             for endpoint, zenoh_form in listen]))
        conf.insert_json5("connect/endpoints", json.dumps([zenoh_form for _, zenoh_form in connect]))
        return conf

    def with_given(self) -> WireSettings:
        """The endpoints used, from the file's and the given ones, as Zenoh's tools take them: given
        listeners add to the process's own (the file's that are not meeting points); given connect
        endpoints replace the file's, and with them its meeting points (listened on and connected to,
        the first process to start gets them), so `--connect` alone binds nothing shared."""
        meeting = [e for e in self.config_listen if e in self.config_connect]
        own = [e for e in self.config_listen if e not in self.config_connect]
        connect = [g.endpoint for g in self.given_connect] or list(self.config_connect)
        listen = [g.endpoint for g in self.given_listen] + ([] if self.given_connect else meeting) + own
        return replace(self, listen=tuple(dict.fromkeys(listen)), connect=tuple(dict.fromkeys(connect)))

    def overridden(self, *, cell_id: str | None = None, listen: list[str] | None = None,
                   connect: list[str] | None = None, security_dir: str | Path | None = None,
                   role: str | None = None, mode: str | None = None, listen_source: str = "--listen",
                   connect_source: str = "--connect", security_source: str = "--security") -> WireSettings:
        """Command-line and environment overrides, validated; `*_source` names the flag or variable
        that gave the endpoints (in messages)."""
        result = self
        if mode:
            if mode not in MODES:
                raise ValueError(f"--mode: must be one of {', '.join(MODES)}, got {mode!r}")
            result = replace(result, mode=mode)
        if security_dir:
            result = replace(result, security=Path(security_dir), security_source=security_source)
        if role:
            result = replace(result, role=role)
        if cell_id:
            result = replace(result, cell_id=check_cell_id(cell_id, "--cell"))
        if listen:
            result = replace(result, given_listen=tuple(Given(check_endpoint(e, listen_source), listen_source)
                                                        for e in listen))
        if connect:
            result = replace(result, given_connect=tuple(
                Given(check_endpoint(e, connect_source), connect_source) for e in connect))
        return result.with_given() if listen or connect else result


def with_endpoint_option(endpoint: str, option: str) -> str:
    """`endpoint` with a Zenoh endpoint config option (`proto/address#key=value;...`)."""
    return f"{endpoint};{option}" if "#" in endpoint else f"{endpoint}#{option}"


def open_session(settings: WireSettings) -> zenoh.Session:
    """Open the Zenoh session: an EndpointError names a required listener that cannot be bound (or
    the router a client cannot reach); a warning names an endpoint given to connect to that nobody
    answers within CONNECT_WARNING_S (Zenoh keeps trying it)."""
    conf = settings.zenoh_config()
    if settings.zenoh_runtime:
        # read by Zenoh when its first session starts; the environment's own value wins
        os.environ.setdefault(ENV_ZENOH_RUNTIME, settings.zenoh_runtime)
    try:
        session = zenoh.open(conf)
    except zenoh.ZError as exc:
        message = open_failure(settings, str(exc))
        if message is None:
            raise
        raise EndpointError(message) from exc
    warn_unanswered(session, settings)
    warn_open_to_network(settings)
    return session


def open_failure(settings: WireSettings, zenoh_message: str) -> str | None:
    """What `zenoh.open`'s error says about the endpoints, in the user's terms; None if not about them."""
    found = OS_ERROR.search(zenoh_message)
    reason = found.group(1) if found else ZENOH_SOURCE_LOCATION.sub("", zenoh_message)
    reason = reason[:1].lower() + reason[1:]
    listen, connect = settings.zenoh_endpoints()
    for endpoint, source in settings.required_listen().items():
        zenoh_form = dict(listen).get(endpoint, endpoint)
        if f"bound to {zenoh_form}#" in zenoh_message or f"bound to {zenoh_form}:" in zenoh_message:
            return f"{source} {endpoint}: {reason}"
    if "Unable to connect to any of" in zenoh_message:   # Zenoh's client: no router reached
        sources = {g.endpoint: g.source for g in settings.given_connect}
        causes = [f"{sources.get(e, 'connect')} {e}: {unreached_cause(settings, e)}" for e, _ in connect]
        return "; ".join(causes) + " (a client cannot start without its router)"
    return None


def unreached_cause(settings: WireSettings, endpoint: str) -> str:
    """Why a client's session could not open at `endpoint`, asked of it directly: nobody listens, or
    the TLS handshake fails (most often: the router's certificate does not name the host dialled)."""
    protocol, _, address = endpoint.split("#", 1)[0].partition("/")
    host, _, port = address.rpartition(":")
    host = host.strip("[]")
    if protocol not in ("tcp", "tls") or not port.isdigit():
        return "nobody answers"
    try:
        probe = socket.create_connection((host, int(port)), timeout=PROBE_TIMEOUT_S)
    except OSError:
        return "nobody answers"
    with probe:
        if settings.security is None:
            return "answers, but no Zenoh session opened with it (a secured router needs --security)"
        from drivers.wire.tls import client_context

        context = client_context(settings.security, settings.role, settings.security_source)
        try:
            with context.wrap_socket(probe, server_hostname=host):
                pass
        except ssl.SSLCertVerificationError as exc:
            if "mismatch" not in str(exc.verify_message).lower():
                return f"answers, but its certificate is refused: {exc.verify_message}"
            names = certificate_names(settings, host, int(port))
            has = f" (it names {names})" if names is not None else ""
            return (f"answers, but its certificate does not name {host}{has}: make the certificates again "
                    f"with `foldcell security init DIR --host {host}`, or connect by a name it has")
        except (ssl.SSLError, OSError) as exc:
            return f"answers, but the TLS handshake fails: {exc}"
    return "answers over TLS, but Zenoh could not open a session with it"


def certificate_names(settings: WireSettings, host: str, port: int) -> str | None:
    """The host names and addresses in the certificate the server at host:port shows (None when it
    could not be read)."""
    from cryptography import x509

    assert settings.security is not None and settings.role is not None
    files = security.identity(settings.security, settings.role, settings.security_source)
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    context.check_hostname = False
    context.verify_mode = ssl.CERT_NONE   # only to read what it shows; nothing is sent over it
    context.load_cert_chain(files.certificate, files.key)
    try:
        with socket.create_connection((host, port), timeout=PROBE_TIMEOUT_S) as raw, \
                context.wrap_socket(raw, server_hostname=host) as tls:
            der = tls.getpeercert(binary_form=True)
    except OSError:
        return None
    if der is None:
        return None
    try:
        names = x509.load_der_x509_certificate(der).extensions.get_extension_for_class(
            x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return "no host"
    return ", ".join([str(n) for n in names.get_values_for_type(x509.DNSName)]
                     + [str(a) for a in names.get_values_for_type(x509.IPAddress)])


def warn_unanswered(session: zenoh.Session, settings: WireSettings) -> None:
    """After CONNECT_WARNING_S, log a warning per given connect endpoint no link reaches. A client is
    not watched (it failed to open without a router, and one router suffices); nor is an endpoint
    the process listens on itself (a meeting point it got)."""
    if settings.is_client:
        return
    listen, connect = settings.zenoh_endpoints()
    listening = {endpoint for endpoint, _ in listen}
    sources = {g.endpoint: g.source for g in settings.given_connect}
    watched = [(sources[e], e, zenoh_form) for e, zenoh_form in connect
               if e in sources and e not in listening]
    if not watched:
        return

    def check() -> None:
        if session.is_closed():
            return
        try:
            reached = [link.dst for link in session.info.links()]
        except zenoh.ZError:   # closed meanwhile
            return
        for source, endpoint, zenoh_form in watched:
            if not any(same_place(zenoh_form, dst) for dst in reached):
                log.warning("%s %s: nobody answers after %g s; Zenoh keeps trying", source, endpoint,
                            CONNECT_WARNING_S)

    timer = threading.Timer(CONNECT_WARNING_S, check)
    timer.daemon = True
    timer.start()


def warn_open_to_network(settings: WireSettings) -> None:
    """An open process (no --security) that listens beyond this machine says so, loudly: anyone who
    reaches the endpoint may read everything and command the robot."""
    if settings.security is not None:
        return
    listen, _ = settings.zenoh_endpoints()
    sources = {g.endpoint: g.source for g in settings.given_listen}
    for endpoint, _zenoh_form in listen:
        if not on_this_machine(endpoint):
            log.warning("%s %s: this process is open (no --security) and listens beyond this machine: anyone "
                        "who can reach it can command the robot. Secure the cell: `foldcell security init "
                        "DIR`, then --security DIR (or FOLDCELL_SECURITY) on every process (README: A "
                        "locked-down cell)", sources.get(endpoint, "listen"), endpoint)


def on_this_machine(endpoint: str) -> bool:
    """Whether an endpoint is reached from this machine only: a loopback address (127.0.0.0/8, ::1), a
    name that resolves to loopback addresses only (localhost), or a Unix socket."""
    protocol, _, address = re.split(r"[?#]", endpoint, maxsplit=1)[0].partition("/")
    if protocol == "unixsock-stream":
        return True
    host = address.rpartition(":")[0].strip("[]")
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:   # a name
        pass
    try:
        addresses = {str(info[4][0]) for info in socket.getaddrinfo(host, None)}
    except (OSError, UnicodeError):
        return False
    return bool(addresses) and all(ipaddress.ip_address(a.split("%", 1)[0]).is_loopback for a in addresses)


def same_place(endpoint: str, locator: str) -> bool:
    """Whether a link's locator (`tcp/127.0.0.1:7448`) is the endpoint given (a host name resolved)."""
    endpoint = endpoint.split("#", 1)[0]
    if endpoint == locator:
        return True
    protocol, _, address = endpoint.partition("/")
    other_protocol, _, other_address = locator.partition("/")
    host, _, port = address.rpartition(":")
    other_host, _, other_port = other_address.rpartition(":")
    if protocol != other_protocol or port != other_port:
        return False
    try:
        addresses = {info[4][0] for info in socket.getaddrinfo(host.strip("[]"), None)}
    except (OSError, UnicodeError):
        return False
    return other_host.strip("[]") in addresses


def endpoint_problem(endpoint: str) -> str | None:
    """Why `endpoint` is not a Zenoh endpoint (None when it is one): `<protocol>/<host>:<port>` (a
    `#` and Zenoh's options may follow), or `unixsock-stream/<path>`."""
    if not ENDPOINT.match(endpoint):
        return "is not a Zenoh endpoint such as tcp/127.0.0.1:7447"
    protocol, _, address = endpoint.split("#", 1)[0].partition("/")
    if protocol == "unixsock-stream":
        return None
    host, colon, port = address.rpartition(":")
    if not colon or not host.strip("[]"):
        return f"needs a host and a port after {protocol}/, such as {protocol}/127.0.0.1:7447"
    if not port.isdigit() or not 0 <= int(port) <= 65535:
        return f"port {port!r} is not a number from 0 to 65535"
    name = host.strip("[]")
    try:
        ipaddress.ip_address(name.split("%", 1)[0])
    except ValueError:
        try:
            socket.getaddrinfo(name, None)
        except (socket.gaierror, UnicodeError) as exc:
            # Zenoh would retry it in the background for ever, silently
            return f"host {name!r} does not resolve ({getattr(exc, 'strerror', None) or exc})"
    return None


def check_endpoint(endpoint: str, field: str) -> str:
    problem = endpoint_problem(endpoint)
    if problem is not None:
        raise ValueError(f"{field}: {endpoint!r} {problem}")
    return endpoint


def check_cell_id(cell_id: str, field: str) -> str:
    if not CELL_ID.match(cell_id):
        raise ValueError(f"{field}: {cell_id!r} must be letters, digits, '_' or '-' (it is a key chunk)")
    return cell_id


def load_wire_settings(path: str | Path | None = None) -> WireSettings:
    default = config_dir() / "cell.yaml"
    f = load_yaml_over(path, default)
    path = Path(path) if path else default
    z = f.sub("zenoh")
    listen = z.strs("listen")
    connect = z.strs("connect", [])
    for name, endpoints in (("listen", listen), ("connect", connect)):
        for i, e in enumerate(endpoints):
            if (problem := endpoint_problem(e)) is not None:
                raise z.error(f"{name}[{i}]", f"{e!r} {problem}")
    cell_id = f.str("cell_id")
    if not CELL_ID.match(cell_id):
        raise f.error("cell_id", "must be letters, digits, '_' or '-'")
    # relative to the file that names it: the given one, else the shipped config/ folder
    candidates = [base / z.str("config") for base in (path.parent, default.parent)]
    zenoh_file = next((c for c in candidates if c.is_file()), candidates[0])
    if not zenoh_file.is_file():
        raise z.error("config", f"{zenoh_file} does not exist")
    runs = Path(f.sub("paths").str("runs"))
    runtime = z.str("runtime", "")
    return WireSettings(cell_id, zenoh_file, listen, connect, runs, path, config_listen=listen,
                        config_connect=connect, zenoh_runtime=runtime)


def settings_from_environment(settings: WireSettings) -> WireSettings:
    def endpoints(var: str) -> list[str] | None:
        value = os.environ.get(var, "").strip()
        return [e.strip() for e in value.split(",") if e.strip()] or None

    return settings.overridden(cell_id=os.environ.get(ENV_CELL) or None, listen=endpoints(ENV_LISTEN),
                               connect=endpoints(ENV_CONNECT),
                               security_dir=os.environ.get(ENV_SECURITY, "").strip() or None,
                               listen_source=ENV_LISTEN, connect_source=ENV_CONNECT,
                               security_source=ENV_SECURITY)
