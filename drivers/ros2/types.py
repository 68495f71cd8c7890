"""RIHS01 type hashes (REP-2016) of the types the cell shows ROS 2, and its services' `.srv` files.

rosbags hashes a message type from the wire's type store. A service's hash covers a description of the
service itself: fields `request_message`, `response_message` and `event_message` (`<Srv>_Event`: a
`service_msgs/msg/ServiceEventInfo` and at most one request and one response), with every type they
reach. That description is built here in a type store of its own and hashed by the same rosbags code.
"""

from __future__ import annotations

from functools import cache
from typing import Any

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.base import Nodetype

from drivers.wire import messages

SRV_SEPARATOR = "---"
EVENT_INFO = "service_msgs/msg/ServiceEventInfo"
# ServiceEventInfo as rosidl hashes it: the .msg's `char[16] client_gid` is uint8[16] in its IDL
# (rosbags' Jazzy store keeps `char`, which would hash differently).
_EVENT_INFO_FIELDS = [
    ("event_type", (Nodetype.BASE, ("uint8", 0))),
    ("stamp", (Nodetype.NAME, "builtin_interfaces/msg/Time")),
    ("client_gid", (Nodetype.ARRAY, ((Nodetype.BASE, ("uint8", 0)), 16))),
    ("sequence_number", (Nodetype.BASE, ("int64", 0))),
]


class ServiceTypeError(ValueError):
    """A `.srv` file that cannot be used: names the file or type and the reason."""


@cache
def message_hash(type_name: str) -> str:
    """`RIHS01_<sha256>` of a message type of the wire's type store."""
    return str(messages.typestore().hash_rihs01(type_name))


def srv_halves(srv_type: str) -> tuple[str, str]:
    """(request, response) definitions of `pkg/srv/Name` from `drivers/wire/msgs/pkg/srv/Name.srv`."""
    package, _, name = srv_type.split("/")
    path = messages.MSG_ROOT / package / "srv" / f"{name}.srv"
    try:
        text = path.read_text()
    except OSError as exc:
        raise ServiceTypeError(f"{srv_type}: cannot read {path}: {exc.strerror or exc}") from exc
    lines = text.splitlines()
    separators = [i for i, line in enumerate(lines) if line.strip() == SRV_SEPARATOR]
    if len(separators) != 1:
        raise ServiceTypeError(f"{path}: needs exactly one '{SRV_SEPARATOR}' line between request and "
                               f"response, found {len(separators)}")
    cut = separators[0]
    return "\n".join(lines[:cut]), "\n".join(lines[cut + 1:])


def _fields(definition: str, srv_type: str, half: str) -> Any:
    try:
        parsed = get_types_from_msg(definition, f"{srv_type.replace('/srv/', '/msg/')}{half}")
    except Exception as exc:
        raise ServiceTypeError(f"{srv_type}{half}: not a valid definition: {exc}") from exc
    return next(iter(parsed.values()))


def _names_reached(fielddefs: Any) -> set[str]:
    """Message types a field list names (directly, or as elements of arrays and sequences)."""
    found = set()
    for _name, desc in fielddefs[1]:
        node, rest = desc
        if node in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            node, rest = rest[0]
        if node == Nodetype.NAME:
            found.add(rest)
    return found


@cache
def service_field_lists(srv_type: str) -> tuple[Any, Any]:
    """The request's and the response's field definitions (rosbags form)."""
    request, response = srv_halves(srv_type)
    return _fields(request, srv_type, "_Request"), _fields(response, srv_type, "_Response")


@cache
def service_hash(srv_type: str) -> str:
    """`RIHS01_<sha256>` of a service type whose `.srv` file is in `drivers/wire/msgs`."""
    return service_hash_of(srv_type, *srv_halves(srv_type))


def service_hash_of(srv_type: str, request_definition: str, response_definition: str) -> str:
    """`RIHS01_<sha256>` of service `pkg/srv/Name` with these request and response definitions (their
    nested message types as the wire defines them)."""
    request = _fields(request_definition, srv_type, "_Request")
    response = _fields(response_definition, srv_type, "_Response")
    req, res, event = f"{srv_type}_Request", f"{srv_type}_Response", f"{srv_type}_Event"
    types: dict[str, Any] = {
        req: request,
        res: response,
        event: ([], [("info", (Nodetype.NAME, EVENT_INFO)),
                     ("request", (Nodetype.SEQUENCE, ((Nodetype.NAME, req), 1))),
                     ("response", (Nodetype.SEQUENCE, ((Nodetype.NAME, res), 1)))]),
        srv_type: ([], [("request_message", (Nodetype.NAME, req)),
                        ("response_message", (Nodetype.NAME, res)),
                        ("event_message", (Nodetype.NAME, event))]),
        EVENT_INFO: ([], _EVENT_INFO_FIELDS),
    }
    wire_store = messages.typestore()
    todo = _names_reached(request) | _names_reached(response) | _names_reached(types[EVENT_INFO])
    while todo:   # the message types the request and response reach, as the wire defines them
        name = todo.pop()
        if name not in types:
            types[name] = wire_store.fielddefs[name]
            todo |= _names_reached(types[name])
    store = get_typestore(Stores.EMPTY)
    store.register(types)
    return str(store.hash_rihs01(srv_type))


def check_layout(srv_type: str, spec: Any) -> None:
    """A service's request and response must be, field for field, the request and reply types of the
    registry key it stands for (`spec`): then the CDR bytes are the same and pass through the bridge."""
    request, response = service_field_lists(srv_type)
    store = messages.typestore()
    for half, fields, type_name in (("request", request, spec.type_name), ("response", response,
                                                                            spec.reply_type)):
        if fields[1] != store.fielddefs[type_name][1]:
            raise ServiceTypeError(f"{srv_type}: its {half} is not laid out as {type_name}, which "
                                   f"{spec.pattern} carries: their CDR bytes would differ")
