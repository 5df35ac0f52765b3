"""rmw_zenoh's wire format, so ROS 2 nodes on Zenoh see Shepherd as one of theirs (no Zenoh
inside: strings and bytes only).

- Data keys: ``<domain>/<topic without the leading slash>/<pkg>::msg::dds_::<Type>_/<hash>``,
  the hash in RIHS01 form (or ``TypeHashNotSupported``, as Humble writes).
- Payload: CDR, little-endian, with its 4-byte encapsulation header (rosbags does it).
- Attachment: int64 sequence number and int64 source time (ns), little-endian, then the 16-byte
  publisher GID preceded by its LEB128 length (0x10): 33 bytes. The GID is the entity's:
  XXH3-128 of its liveliness token, low then high 64 bits, little-endian
  (rmw_zenoh_cpp ``liveliness::Entity``).
- Discovery: liveliness tokens ``@ros2_lv/<domain>/<zid>/<nid>/<eid>/<kind>/<enclave>/<ns>/
  <node>[/<topic>/<type>/<hash>/<qos>]``, '/' inside names written '%' and '%' for empty.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from functools import cache
from typing import Any, Literal

import xxhash
from rosbags.typesys import Stores, get_typestore

NO_HASH = "TypeHashNotSupported"
ATTACHMENT_SIZE = 33
_ATTACHMENT = struct.Struct("<qqB16s")


@cache
def typestore() -> Any:
    """rosbags' message definitions of ROS 2 Jazzy (also what computes the RIHS01 hashes)."""
    return get_typestore(Stores.ROS2_JAZZY)


def dds_type_name(ros_type: str) -> str:
    """``std_msgs/msg/String`` -> ``std_msgs::msg::dds_::String_``."""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def type_hash(ros_type: str, with_hash: bool = True) -> str:
    """The type's RIHS01 hash (``RIHS01_`` + 64 hex), or Humble's ``TypeHashNotSupported``."""
    return str(typestore().hash_rihs01(ros_type)) if with_hash else NO_HASH


def data_key(domain_id: int, topic: str, ros_type: str, with_hash: bool = True,
             hash_: str | None = None) -> str:
    """The Zenoh key of a ROS 2 topic's samples (or of a service's queries, with the service
    type and its ``hash_``)."""
    if not topic.startswith("/") or "//" in topic or topic.endswith("/"):
        raise ValueError(f"ROS topic {topic!r} must be absolute, like /shepherd/humanoid/pose")
    return (f"{domain_id}/{topic[1:]}/{dds_type_name(ros_type)}/"
            f"{_hash(ros_type, with_hash, hash_)}")


def _hash(ros_type: str, with_hash: bool, hash_: str | None) -> str:
    return NO_HASH if not with_hash else hash_ or type_hash(ros_type)


def mangle(name: str) -> str:
    """A name inside a token: '/' written '%', and '%' alone for an empty name or '/'."""
    return "%" if name in ("", "/") else name.replace("/", "%")


@dataclass(frozen=True)
class Qos:
    """The QoS a token advertises; rmw_zenoh leaves fields at its defaults empty
    (reliable, volatile, keep last, depth 42, infinite deadline/lifespan, automatic)."""

    reliability: Literal["reliable", "best_effort"] = "reliable"
    durability: Literal["volatile", "transient_local"] = "volatile"
    depth: int = 10
    lifespan_s: int = 0  # 0: infinite

    def key(self) -> str:
        rel = "" if self.reliability == "reliable" else "2"
        dur = "" if self.durability == "volatile" else "1"
        depth = "" if self.depth == 42 else str(self.depth)
        lifespan = f"{self.lifespan_s}," if self.lifespan_s else ","
        return f"{rel}:{dur}:,{depth}:,:{lifespan}:,,"


def node_token(domain_id: int, zid: str, node_id: int, node: str, namespace: str = "/",
               enclave: str = "/") -> str:
    """The ``NN`` token of a node (its id repeated as the entity id)."""
    return (f"@ros2_lv/{domain_id}/{zid}/{node_id}/{node_id}/NN/{mangle(enclave)}/"
            f"{mangle(namespace)}/{node}")


def entity_token(domain_id: int, zid: str, node_id: int, entity_id: int,
                 kind: Literal["MP", "MS", "SS"], node: str, topic: str, ros_type: str,
                 qos: Qos, *, namespace: str = "/", enclave: str = "/",
                 with_hash: bool = True, hash_: str | None = None) -> str:
    """The ``MP`` (publisher), ``MS`` (subscription) or ``SS`` (service server) token of an
    endpoint."""
    return (f"@ros2_lv/{domain_id}/{zid}/{node_id}/{entity_id}/{kind}/{mangle(enclave)}/"
            f"{mangle(namespace)}/{node}/{mangle(topic)}/{dds_type_name(ros_type)}/"
            f"{_hash(ros_type, with_hash, hash_)}/{qos.key()}")


def entity_gid(token: str) -> bytes:
    """The 16-byte GID rmw_zenoh gives the entity with this liveliness token (what
    ``ros2 topic info -v`` and ``message_info.publisher_gid`` show)."""
    h = xxhash.xxh3_128_intdigest(token.encode())
    return (h & 0xFFFF_FFFF_FFFF_FFFF).to_bytes(8, "little") + (h >> 64).to_bytes(8, "little")


def pack_attachment(sequence: int, source_time_ns: int, gid: bytes) -> bytes:
    """What rmw_zenoh needs with every sample (it drops samples without it)."""
    if len(gid) != 16:
        raise ValueError(f"a publisher GID is 16 bytes, got {len(gid)}")
    return _ATTACHMENT.pack(sequence, source_time_ns, 16, gid)


def unpack_attachment(data: bytes) -> tuple[int, int, bytes]:
    """(sequence, source time ns, GID); raises ValueError for anything else."""
    if len(data) != ATTACHMENT_SIZE or data[16] != 16:
        raise ValueError(f"an rmw_zenoh attachment is {ATTACHMENT_SIZE} bytes with a GID "
                         f"length of 16, got {len(data)} bytes")
    sequence, stamp, _, gid = _ATTACHMENT.unpack(data)
    return sequence, stamp, gid


def serialize(message: Any, ros_type: str) -> bytes:
    """CDR with its encapsulation header."""
    return bytes(typestore().serialize_cdr(message, ros_type))


def deserialize(data: bytes, ros_type: str) -> Any:
    return typestore().deserialize_cdr(data, ros_type)
