"""An independent ROS 2 peer for the tests: ``zenoh-ros2-sdk`` (PyPI; nobody here wrote it),
which computes RIHS01 hashes itself from ``.msg`` files, builds rmw_zenoh's keys and reads the
liveliness tokens.

Left to itself the SDK git-clones the ROS message repositories to find the ``.msg`` files;
offline (CI has no such network) it is handed the definitions from rosbags' own store, written
out as ``<pkg>/msg/<Name>.msg`` (and the few ``.srv`` files rosbags lacks, as ROS ships them),
and cloning is made to fail loudly. The SDK is a process-wide singleton: ``open_peer`` points
it at one router and ``close`` resets it. Its session is a Zenoh client of the router: as a
peer it meets each new session directly, and a one-shot liveliness query it makes meanwhile
(as its transient-local subscriber does once, at creation) came back empty about one time in
two; rmw_zenoh's own subscribers follow liveliness instead of asking once.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from services.ros2_bridge import rmw

#: The services of ROS 2's parameter interface (rcl_interfaces/srv, Jazzy), as shipped but for
#: the message types' full names (the SDK's rosbags would resolve a short name in a .srv into
#: ``rcl_interfaces/srv/msg/...``).
SRV_DEFINITIONS = {
    "ListParameters": (
        "uint64 DEPTH_RECURSIVE=0\nstring[] prefixes\nuint64 depth\n---\n"
        "rcl_interfaces/msg/ListParametersResult result\n"),
    "GetParameters": "string[] names\n---\nrcl_interfaces/msg/ParameterValue[] values\n",
    "DescribeParameters": (
        "string[] names\n---\nrcl_interfaces/msg/ParameterDescriptor[] descriptors\n"),
    "GetParameterTypes": "string[] names\n---\nuint8[] types\n",
}
_SEPARATOR = "=" * 80 + "\nMSG: "


def write_definitions(root: Path, ros_types: Iterable[str]) -> None:
    """``root/<pkg>/msg/<Name>.msg`` for each type and everything it uses (from rosbags),
    and ``root/rcl_interfaces/srv/*.srv``."""
    store = rmw.typestore()
    for ros_type in ros_types:
        text, _ = store.generate_msgdef(ros_type, ros_version=2)
        sections = text.split(_SEPARATOR)
        named = [(ros_type, sections[0])]
        for section in sections[1:]:
            name, _, body = section.partition("\n")
            package, _, leaf = name.partition("/")
            named.append((f"{package}/msg/{leaf}", body))
        for name, body in named:
            package, _, leaf = name.split("/")
            path = root / package / "msg" / f"{leaf}.msg"
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(body.strip() + "\n")
    for name, body in SRV_DEFINITIONS.items():
        path = root / "rcl_interfaces" / "srv" / f"{name}.srv"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(body)


def _offline(*args: Any, **kwargs: Any) -> Any:
    raise RuntimeError("offline: the tests hand zenoh-ros2-sdk its definitions; no git clone")


def open_peer(root: Path, router: str, ros_types: Iterable[str]) -> Any:
    """The SDK's session, connected to ``router`` (tcp/127.0.0.1:<port>), its registry reading
    the definitions written under ``root``."""
    import zenoh_ros2_sdk._cache as cache
    import zenoh_ros2_sdk.message_registry as registry
    from zenoh_ros2_sdk import ZenohSession

    write_definitions(root, ros_types)
    cache.clone_to_cache = _offline
    registry.clone_to_cache = _offline
    registry.get_message_file_path = _offline
    registry._registry = registry.MessageRegistry(str(root))
    host, port = router.removeprefix("tcp/").rsplit(":", 1)
    ZenohSession._instance = None
    os.environ["ZENOH_CONFIG_OVERRIDE"] = 'mode="client"'
    try:
        return ZenohSession.get_instance(host, int(port))
    finally:
        del os.environ["ZENOH_CONFIG_OVERRIDE"]


def close_peer() -> None:
    import zenoh_ros2_sdk.message_registry as registry
    from zenoh_ros2_sdk import ZenohSession

    if ZenohSession._instance is not None:
        ZenohSession._instance.close()
    ZenohSession._instance = None
    registry._registry = None
