"""ROS 2's parameter services, read-only, answered with the bridge's settings (no Zenoh inside):
``ros2 param list /shepherd_bridge`` and ``ros2 param get``/``describe`` work.

rosbags has no service types: the request and response of each are defined here as ROS ships
them (rcl_interfaces/srv, Jazzy) and registered in the typestore, with the service type itself
(``request_message``, ``response_message``, ``event_message``; the event holding
``service_msgs/ServiceEventInfo`` and at most one request and one response), which is what its
RIHS01 hash covers. ServiceEventInfo's ``char[16] client_gid`` is ``uint8[16]`` in ROS 2's type
description (rosidl maps .msg ``char`` to uint8); rosbags hashes it as ``char``, so the hash is
taken over the corrected description. Checked against rmw_zenoh's documented
``example_interfaces/srv/AddTwoInts`` hash (tests).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import cache
from typing import Any

import numpy as np
from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.msg import get_types_from_msg

from services.ros2_bridge.rmw import typestore

#: rcl_interfaces' read services, request and response as shipped (names fully qualified)
PARAMETER_SERVICES = {
    "list_parameters": ("rcl_interfaces/srv/ListParameters",
                        "string[] prefixes\nuint64 depth",
                        "rcl_interfaces/msg/ListParametersResult result"),
    "get_parameters": ("rcl_interfaces/srv/GetParameters",
                       "string[] names",
                       "rcl_interfaces/msg/ParameterValue[] values"),
    "describe_parameters": ("rcl_interfaces/srv/DescribeParameters",
                            "string[] names",
                            "rcl_interfaces/msg/ParameterDescriptor[] descriptors"),
    "get_parameter_types": ("rcl_interfaces/srv/GetParameterTypes",
                            "string[] names",
                            "uint8[] types"),
}
_EVENT_INFO = "service_msgs/msg/ServiceEventInfo"
# rcl_interfaces/msg/ParameterType
NOT_SET, BOOL, INTEGER, DOUBLE, STRING, DOUBLE_ARRAY = 0, 1, 2, 3, 4, 8


def _fields(text: str, name: str) -> Any:
    (_, definition), = get_types_from_msg(text, name).items()
    return definition


def register_service(store: Any, srv_type: str, request: str, response: str) -> None:
    """Register ``<srv_type>_Request``/``_Response``/``_Event`` and the service type."""
    req, resp, event = f"{srv_type}_Request", f"{srv_type}_Response", f"{srv_type}_Event"
    if srv_type in store.fielddefs:
        return
    store.register({
        req: _fields(request, req), resp: _fields(response, resp),
        event: ([], [("info", (Nodetype.NAME, _EVENT_INFO)),
                     ("request", (Nodetype.SEQUENCE, ((Nodetype.NAME, req), 1))),
                     ("response", (Nodetype.SEQUENCE, ((Nodetype.NAME, resp), 1)))]),
        srv_type: ([], [("request_message", (Nodetype.NAME, req)),
                        ("response_message", (Nodetype.NAME, resp)),
                        ("event_message", (Nodetype.NAME, event))])})


@cache
def _hash_store() -> Any:
    """A typestore of its own whose ServiceEventInfo is described as ROS 2 describes it."""
    store = get_typestore(Stores.ROS2_JAZZY)
    consts, fields = store.fielddefs[_EVENT_INFO]
    store.fielddefs[_EVENT_INFO] = (consts, [
        (n, (Nodetype.ARRAY, ((Nodetype.BASE, ("uint8", 0)), 16))) if n == "client_gid" else
        (n, d) for n, d in fields])
    return store


def service_type_hash(srv_type: str, request: str, response: str) -> str:
    """RIHS01 hash of a service type from its request and response definitions."""
    store = _hash_store()
    register_service(store, srv_type, request, response)
    return str(store.hash_rihs01(srv_type))


def parameter_value(value: Any) -> Any:
    """rcl_interfaces/ParameterValue of a setting (None: not set)."""
    T = typestore().types["rcl_interfaces/msg/ParameterValue"]
    kind, field = (
        (BOOL, "bool_value") if isinstance(value, bool) else
        (INTEGER, "integer_value") if isinstance(value, int) else
        (DOUBLE, "double_value") if isinstance(value, float) else
        (DOUBLE_ARRAY, "double_array_value") if isinstance(value, (tuple, list)) else
        (NOT_SET, None) if value is None else (STRING, "string_value"))
    values: dict[str, Any] = dict(
        type=kind, bool_value=False, integer_value=0, double_value=0.0, string_value="",
        byte_array_value=_array("uint8"), bool_array_value=_array("bool"),
        integer_array_value=_array("int64"), double_array_value=_array("float64"),
        string_array_value=[])
    if field == "double_array_value":
        values[field] = _array("float64", [float(v) for v in value])
    elif field is not None:
        values[field] = str(value) if kind == STRING else value
    return T(**values)


def _array(dtype: str, values: list[Any] | None = None) -> np.ndarray:
    return np.array(values or [], dtype=dtype)


class Parameters:
    """The bridge's settings as read-only ROS 2 parameters, answering the four read services."""

    def __init__(self, settings: dict[str, Any], descriptions: dict[str, str]) -> None:
        self.settings = settings
        self.descriptions = descriptions
        for srv_type, request, response in PARAMETER_SERVICES.values():
            register_service(typestore(), srv_type, request, response)

    def handler(self, service: str) -> Callable[[Any], Any]:
        """The function answering ``service`` (a key of PARAMETER_SERVICES)."""
        return {"list_parameters": self.list_parameters, "get_parameters": self.get_parameters,
                "describe_parameters": self.describe_parameters,
                "get_parameter_types": self.get_parameter_types}[service]

    def _response(self, service: str, **fields: Any) -> Any:
        return typestore().types[f"{PARAMETER_SERVICES[service][0]}_Response"](**fields)

    def list_parameters(self, request: Any) -> Any:
        prefixes = list(request.prefixes)
        names = [n for n in self.settings
                 if not prefixes or any(n == p or n.startswith(p + ".") for p in prefixes)]
        result = typestore().types["rcl_interfaces/msg/ListParametersResult"](
            names=names, prefixes=[])
        return self._response("list_parameters", result=result)

    def get_parameters(self, request: Any) -> Any:
        return self._response("get_parameters", values=[
            parameter_value(self.settings.get(n)) for n in request.names])

    def get_parameter_types(self, request: Any) -> Any:
        return self._response("get_parameter_types", types=_array("uint8", [
            parameter_value(self.settings.get(n)).type for n in request.names]))

    def describe_parameters(self, request: Any) -> Any:
        D = typestore().types["rcl_interfaces/msg/ParameterDescriptor"]
        return self._response("describe_parameters", descriptors=[D(
            name=n, type=parameter_value(self.settings.get(n)).type,
            description=self.descriptions.get(n, ""), additional_constraints="",
            read_only=True, dynamic_typing=False, floating_point_range=[], integer_range=[])
            for n in request.names])
