"""`config/ros2.yaml`: how `foldcell ros2` shows the cell to ROS 2 nodes on rmw_zenoh."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from drivers.common.configfile import ConfigError, Fields, config_dir, load_yaml
from drivers.ros2.names import RELIABILITIES, Qos, RosNameError, check_token
from drivers.wire.messages import WireError
from drivers.wire.registry import spec_for
from drivers.wire.settings import check_endpoint

CONFIG_FILE = "ros2.yaml"
ENV_DOMAIN = "ROS_DOMAIN_ID"
MAX_DOMAIN_ID = 232   # ROS 2's domain ids: 0..232 (REP on domain ids, DDS port arithmetic)


@dataclass(frozen=True)
class Ros2Config:
    connect: tuple[str, ...]
    zenoh_config: Path
    domain_id: int
    namespace: str
    node_name: str
    stream_qos: Qos
    other_qos: Qos
    services: dict[str, str]   # foldcell queryable key -> pkg/srv/Type
    service_qos: Qos
    service_timeout_s: float


def _qos(f: Fields, name: str) -> Qos:
    sub = f.sub(name)
    sub.reject_unknown({"reliability", "depth"})
    reliability = sub.str("reliability")
    if reliability not in RELIABILITIES:
        raise sub.error("reliability", f"must be one of {', '.join(RELIABILITIES)}, got {reliability!r}")
    return Qos(RELIABILITIES[reliability], sub.int("depth", min=1))


def ros2_config_from_fields(f: Fields, config_root: Path) -> Ros2Config:
    f.reject_unknown(set(Ros2Config.__dataclass_fields__))
    namespace = f.str("namespace")
    try:
        for chunk in namespace.strip("/").split("/"):
            check_token(chunk, "namespace chunk")
        check_token(f.str("node_name"), "node name")
    except RosNameError as exc:
        raise ConfigError(f.file, f.path("namespace"), str(exc)) from exc
    if not namespace.startswith("/"):
        raise f.error("namespace", f"must start with '/', got {namespace!r}")
    services = f.sub("services")
    service_keys = services.keys()
    for key in service_keys:
        try:
            spec = spec_for(key)
        except WireError as exc:
            raise services.error(key, str(exc)) from exc
        if spec.kind != "queryable":
            raise services.error(key, f"is a {spec.kind} of the registry, not a queryable")
        if services.str(key).count("/srv/") != 1:
            raise services.error(key, f"must name a pkg/srv/Type, got {services.str(key)!r}")
    try:
        connect = tuple(check_endpoint(e, f.path("connect")) for e in f.strs("connect"))
    except ValueError as exc:
        raise ConfigError(f.file, f.path("connect"), str(exc)) from exc
    return Ros2Config(
        connect=connect,
        zenoh_config=config_root / f.str("zenoh_config"),
        domain_id=f.int("domain_id", min=0, max=MAX_DOMAIN_ID),
        namespace=namespace.rstrip("/"),
        node_name=f.str("node_name"),
        stream_qos=_qos(f, "stream_qos"),
        other_qos=_qos(f, "other_qos"),
        services={key: services.str(key) for key in service_keys},
        service_qos=_qos(f, "service_qos"),
        service_timeout_s=f.float("service_timeout_s", positive=True),
    )


def load_ros2_config(path: str | Path | None = None) -> Ros2Config:
    file = Path(path) if path else config_dir() / CONFIG_FILE
    return ros2_config_from_fields(load_yaml(file).sub("ros2"), file.parent)


def check_domain_id(value: str, source: str) -> int:
    """A domain id given on the command line or in ROS_DOMAIN_ID."""
    try:
        domain = int(value)
    except ValueError:
        raise ValueError(f"{source}: must be a whole number 0..{MAX_DOMAIN_ID}, got {value!r}") from None
    if not 0 <= domain <= MAX_DOMAIN_ID:
        raise ValueError(f"{source}: must be 0..{MAX_DOMAIN_ID}, got {domain}")
    return domain
