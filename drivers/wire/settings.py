"""Where a process meets the others: cell id, Zenoh settings and endpoints (config/cell.yaml)."""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass, replace
from pathlib import Path

import zenoh

from drivers.common.configfile import ConfigError, config_dir, load_yaml_over
from drivers.wire import security

ENV_CELL = "FOLDCELL_CELL"
ENV_LISTEN = "FOLDCELL_LISTEN"        # comma-separated endpoints, like --listen
ENV_CONNECT = "FOLDCELL_CONNECT"
ENV_SECURITY = security.ENV_SECURITY  # a security directory, like --security
ENDPOINT = re.compile(r"^(tcp|udp|tls|quic|ws|unixsock-stream)/.+")
CELL_ID = re.compile(r"^[A-Za-z0-9_\-]+$")
MODES = ("peer", "client")   # a process's Zenoh mode (a router is `foldcell router`)


@dataclass(frozen=True)
class WireSettings:
    cell_id: str
    zenoh_config_file: Path
    listen: tuple[str, ...]
    connect: tuple[str, ...]
    runs_directory: Path
    config_file: Path  # the file these came from; other rooms read their own sections of it
    security: Path | None = None   # a `foldcell security init` directory: mutual TLS and access control
    role: str = ""                 # the process's role there (config/security.yaml)
    mode: str = ""                 # Zenoh mode over the config file's: "peer", or "client" of a router

    def zenoh_config(self) -> zenoh.Config:
        try:
            conf = zenoh.Config.from_file(str(self.zenoh_config_file))
        except Exception as exc:
            raise ConfigError(self.zenoh_config_file, "", f"not a valid Zenoh config: {exc}") from exc
        listen, connect = list(self.listen), list(self.connect)
        if self.mode:
            conf.insert_json5("mode", json.dumps(self.mode))
            if self.mode == "client":   # a client reaches its router and serves nothing
                listen = []
        if self.security is not None:
            if not self.role:
                raise security.SecurityError("this command has no role to run secured in")
            listen = [security.tls_endpoint(e) for e in listen]
            connect = [security.tls_endpoint(e) for e in connect]
            if self.role != security.ROUTER_ROLE:   # a client reaches the router and serves nothing
                listen = []
            for path, value in security.secure_zenoh_settings(self.security, self.role, self.cell_id).items():
                conf.insert_json5(path, value)
        if self.role == security.ROUTER_ROLE:       # it serves the endpoints; other routers it may join
            conf.insert_json5("mode", json.dumps("router"))
            connect = [e for e in connect if e not in listen]
        conf.insert_json5("listen/endpoints", json.dumps(listen))
        conf.insert_json5("connect/endpoints", json.dumps(connect))
        return conf

    def overridden(self, *, cell_id: str | None = None, listen: list[str] | None = None,
                   connect: list[str] | None = None, security_dir: str | Path | None = None,
                   role: str | None = None, mode: str | None = None) -> WireSettings:
        """Command-line and environment overrides, validated."""
        result = self
        if mode:
            if mode not in MODES:
                raise ValueError(f"--mode: must be one of {', '.join(MODES)}, got {mode!r}")
            result = replace(result, mode=mode)
        if security_dir:
            result = replace(result, security=Path(security_dir))
        if role:
            result = replace(result, role=role)
        if cell_id:
            result = replace(result, cell_id=check_cell_id(cell_id, "--cell"))
        if listen:
            result = replace(result, listen=tuple(check_endpoint(e, "--listen") for e in listen))
        if connect:
            result = replace(result, connect=tuple(check_endpoint(e, "--connect") for e in connect))
        return result


def check_endpoint(endpoint: str, field: str) -> str:
    if not ENDPOINT.match(endpoint):
        raise ValueError(f"{field}: {endpoint!r} is not a Zenoh endpoint such as tcp/127.0.0.1:7447")
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
    for i, e in enumerate(listen):
        if not ENDPOINT.match(e):
            raise z.error(f"listen[{i}]", f"{e!r} is not a Zenoh endpoint")
    for i, e in enumerate(connect):
        if not ENDPOINT.match(e):
            raise z.error(f"connect[{i}]", f"{e!r} is not a Zenoh endpoint")
    cell_id = f.str("cell_id")
    if not CELL_ID.match(cell_id):
        raise f.error("cell_id", "must be letters, digits, '_' or '-'")
    # relative to the file that names it: the given one, else the shipped config/ folder
    candidates = [base / z.str("config") for base in (path.parent, default.parent)]
    zenoh_file = next((c for c in candidates if c.is_file()), candidates[0])
    if not zenoh_file.is_file():
        raise z.error("config", f"{zenoh_file} does not exist")
    runs = Path(f.sub("paths").str("runs"))
    return WireSettings(cell_id, zenoh_file, listen, connect, runs, path)


def settings_from_environment(settings: WireSettings) -> WireSettings:
    def endpoints(var: str) -> list[str] | None:
        value = os.environ.get(var, "").strip()
        return [e.strip() for e in value.split(",") if e.strip()] or None

    return settings.overridden(cell_id=os.environ.get(ENV_CELL) or None, listen=endpoints(ENV_LISTEN),
                               connect=endpoints(ENV_CONNECT),
                               security_dir=os.environ.get(ENV_SECURITY, "").strip() or None)
