"""rmw_zenoh naming and framing (pure encoding, no I/O): what a ROS 2 node on `rmw_zenoh_cpp`
expects to see on Zenoh, written from rmw_zenoh's design document (`docs/design.md`, sections
"Topic and Service name mapping to Zenoh key expressions", "Graph Cache", "Publishers").

* Data key expression: `<domain_id>/<fully qualified topic name without the leading '/'>/
  <DDS type name>/<type hash>`, e.g. `0/robot1/tf/tf2_msgs::msg::dds_::TFMessage_/RIHS01_e369...`.
* Liveliness tokens (the ROS graph: `ros2 node list`, `ros2 topic list/info`):
  node `@ros2_lv/<domain>/<zid>/<node id>/<node id>/NN/<enclave>/<namespace>/<node name>`;
  publisher / subscription `@ros2_lv/<domain>/<zid>/<node id>/<entity id>/MP|MS/<enclave>/
  <namespace>/<node name>/<topic>/<DDS type name>/<type hash>/<qos>`, every name "mangled"
  ('/' -> '%'; an empty namespace or enclave is '%'). `<qos>` is rmw_zenoh's compact QoS text:
  `reliability:durability:history,depth:deadline_s,deadline_ns:lifespan_s,lifespan_ns:
  liveliness,lease_s,lease_ns`, each value empty where it equals rmw_zenoh's default
  (RELIABLE, VOLATILE, KEEP_LAST, depth 42, infinite durations, AUTOMATIC) and otherwise the
  number of the `rmw_qos_*_policy_e` enumerator (ros2/rmw `rmw/types.h`).
* Per-sample attachment (33 bytes): int64 little-endian sequence number (from 1 per
  publisher), int64 little-endian source timestamp (ns since the UNIX epoch), one byte GID
  length (16), the 16-byte publisher GID.

The type hash (RIHS01, REP-2011) is computed by the `rosbags` type store from the message
definition; the GID is 16 bytes of BLAKE2b over the entity's liveliness key (rmw_zenoh hashes
the same key with XXH3-128; a GID is an opaque, unique id of the entity).

Two ROS 2 distributions (`Ros2Distro`, setting `zenoh.ros2_distro`), read from rmw_zenoh's
release sources (ros2-gbp/rmw_zenoh-release, branches `release/humble/rmw_zenoh_cpp` 0.1.9 and
`release/jazzy/rmw_zenoh_cpp` 0.2.10, `src/detail/`):

* Jazzy: the `<type hash>` of data keys and tokens is the RIHS01 hash (`rmw_publisher_data.cpp`
  / `rmw_subscription_data.cpp` stringify `get_type_hash_func`); Kilted's sources do the same.
* Humble: ROS 2 Humble's type support has no type hash (REP-2011 came with Iron), so its
  rmw_zenoh writes the constant `TypeHashNotSupported` in that same place (the same two files),
  keeping the key and token layout. Everything else is the same in both: `TopicInfo` and
  `Entity` in `liveliness_utils.cpp` build the key and the token alike (admin space `@ros2_lv`,
  `NN`/`MP`/`MS`, '%' mangling), the QoS text has the same fields, defaults (`qos.cpp`: depth
  42, RELIABLE, VOLATILE) and enumerator numbers (Humble lacks only BEST_AVAILABLE, which
  LiteVLoc never sends), and the attachment (`attachment_helpers.cpp`) is the same zenoh-ext
  serialization of int64, int64 and a 16-byte GID (Humble hard-codes 16 where Jazzy uses
  `RMW_GID_STORAGE_SIZE`, which is 16 there; Humble's `rmw_gid_t` itself holds 24 bytes).
  A subscriber matches only its exact key, so a wrong distribution delivers no data while the
  graph (`ros2 topic list`, built from tokens by name and type) still shows the topic.
"""

from __future__ import annotations

import hashlib
import os
import struct
from collections.abc import Mapping
from dataclasses import dataclass
from enum import Enum, IntEnum

from litevloc.base.errors import LiteVLocError
from litevloc.hw import ros_msgs

ADMIN_SPACE = "@ros2_lv"
GID_SIZE = 16
ATTACHMENT_SIZE = 8 + 8 + 1 + GID_SIZE
# what Humble's rmw_zenoh writes where Jazzy's writes the RIHS01 type hash
HUMBLE_TYPE_HASH = "TypeHashNotSupported"


class Ros2Distro(Enum):
    """The ROS 2 distribution whose rmw_zenoh LiteVLoc's keys and tokens must match."""

    JAZZY = "jazzy"
    HUMBLE = "humble"


class Ros2DistroError(LiteVLocError, ValueError):
    """`zenoh.ros2_distro: auto` and `ROS_DISTRO` is unset or names no supported distribution."""


def resolve_distro(setting: str, environ: Mapping[str, str] | None = None) -> Ros2Distro:
    """The distribution of `zenoh.ros2_distro` ("jazzy", "humble" or "auto"); `auto` reads
    `ROS_DISTRO` (of `environ`, default the process environment) as a sourced ROS 2 sets it."""
    if setting != "auto":
        return Ros2Distro(setting)
    env = os.environ if environ is None else environ
    name = env.get("ROS_DISTRO", "").strip().lower()
    known = [d.value for d in Ros2Distro]
    if not name:
        raise Ros2DistroError(f"zenoh.ros2_distro is 'auto' but ROS_DISTRO is not set: source the robot's ROS 2 "
                              f"(setup.bash) or set zenoh.ros2_distro to one of {known}")
    if name not in known:
        raise Ros2DistroError(f"zenoh.ros2_distro is 'auto' and ROS_DISTRO is {name!r}, which LiteVLoc's rmw_zenoh "
                              f"naming does not support; set zenoh.ros2_distro to one of {known}")
    return Ros2Distro(name)


class Reliability(IntEnum):
    """`rmw_qos_reliability_policy_e`."""

    RELIABLE = 1
    BEST_EFFORT = 2


class Durability(IntEnum):
    """`rmw_qos_durability_policy_e`."""

    TRANSIENT_LOCAL = 1
    VOLATILE = 2


class History(IntEnum):
    """`rmw_qos_history_policy_e`."""

    KEEP_LAST = 1
    KEEP_ALL = 2


@dataclass(frozen=True)
class Qos:
    """A topic's ROS 2 QoS (deadline, lifespan and liveliness left at their defaults: infinite, AUTOMATIC)."""

    reliability: Reliability = Reliability.RELIABLE
    durability: Durability = Durability.VOLATILE
    history: History = History.KEEP_LAST
    depth: int = 10


# rmw_zenoh's default profile (rmw_zenoh_cpp `qos.cpp`): fields equal to it are left empty in the token
DEFAULT_DEPTH = 42


def qos_keyexpr(qos: Qos) -> str:
    """The `<qos>` part of a liveliness token, e.g. `::,10:,:,:,,` (depth 10, all else default)."""
    rel = "" if qos.reliability == Reliability.RELIABLE else str(int(qos.reliability))
    dur = "" if qos.durability == Durability.VOLATILE else str(int(qos.durability))
    hist = "" if qos.history == History.KEEP_LAST else str(int(qos.history))
    depth = "" if qos.depth == DEFAULT_DEPTH else str(int(qos.depth))
    return f"{rel}:{dur}:{hist},{depth}:,:,:,,"


def mangle(name: str) -> str:
    """'/' -> '%' (a liveliness key chunk); the empty name (root namespace, no enclave) is '%'."""
    return name.replace("/", "%") if name else "%"


def dds_type_name(typename: str) -> str:
    """`geometry_msgs/msg/PoseStamped` -> `geometry_msgs::msg::dds_::PoseStamped_`."""
    pkg, kind, name = typename.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def type_hash(typename: str) -> str:
    """`RIHS01_<sha256 hex>` of the message type (REP-2011), from the rosbags type store."""
    return str(ros_msgs.typestore().hash_rihs01(typename))


def key_type_hash(typename: str, distro: Ros2Distro) -> str:
    """The `<type hash>` chunk of keys and tokens: RIHS01 for Jazzy, Humble's placeholder."""
    if distro is Ros2Distro.HUMBLE:
        return HUMBLE_TYPE_HASH
    return type_hash(typename)


def ros_namespace(namespace: str) -> str:
    """The configured namespace (`robot1`, `a/b` or "") as a ROS namespace (`/robot1`, `/a/b`, `/`)."""
    return "/" + namespace.strip("/")


def fully_qualified(namespace: str, topic: str) -> str:
    """ROS name resolution: `("robot1", "litevloc/pose")` -> `/robot1/litevloc/pose`; an absolute
    name (`/tf`) is not namespaced."""
    if topic.startswith("/"):
        return topic
    ns = namespace.strip("/")
    return f"/{ns}/{topic}" if ns else f"/{topic}"


def topic_keyexpr(domain_id: int, fq_topic: str, typename: str, distro: Ros2Distro = Ros2Distro.JAZZY) -> str:
    """The Zenoh key of a topic's data (`fq_topic` fully qualified, with the leading '/')."""
    return f"{domain_id}/{fq_topic.strip('/')}/{dds_type_name(typename)}/{key_type_hash(typename, distro)}"


@dataclass(frozen=True)
class NodeIdentity:
    """Who declares the entities: one ROS node in one Zenoh session (a ROS context)."""

    domain_id: int
    zid: str  # the Zenoh session id as Zenoh prints it (hex)
    node_id: int
    namespace: str  # ROS namespace, `/` or `/robot1`
    node_name: str
    enclave: str = ""
    distro: Ros2Distro = Ros2Distro.JAZZY  # decides the type hash chunk of its endpoint tokens

    def _head(self, entity_id: int, kind: str) -> str:
        return (f"{ADMIN_SPACE}/{self.domain_id}/{self.zid}/{self.node_id}/{entity_id}/{kind}/"
                f"{mangle(self.enclave)}/{mangle(self.namespace.strip('/') and self.namespace)}/{self.node_name}")

    def node_token(self) -> str:
        """The node's liveliness key (`NN`)."""
        return self._head(self.node_id, "NN")

    def endpoint_token(self, entity_id: int, kind: str, fq_topic: str, typename: str, qos: Qos) -> str:
        """A publisher's (`MP`) or subscription's (`MS`) liveliness key."""
        if kind not in ("MP", "MS"):
            raise ValueError(f"entity kind must be MP or MS, got {kind!r}")
        return (f"{self._head(entity_id, kind)}/{mangle(fq_topic)}/{dds_type_name(typename)}/"
                f"{key_type_hash(typename, self.distro)}/{qos_keyexpr(qos)}")


def entity_gid(liveliness_key: str) -> bytes:
    """16-byte GID of the entity whose liveliness key this is."""
    return hashlib.blake2b(liveliness_key.encode(), digest_size=GID_SIZE).digest()


def attachment(sequence_number: int, source_timestamp_ns: int, gid: bytes) -> bytes:
    """The per-sample attachment rmw_zenoh subscribers read (see the module docstring)."""
    if len(gid) != GID_SIZE:
        raise ValueError(f"GID must be {GID_SIZE} bytes, got {len(gid)}")
    return struct.pack("<qqB", sequence_number, source_timestamp_ns, GID_SIZE) + gid


def attachment_fields(data: bytes) -> tuple[int, int, bytes] | None:
    """(sequence number, source timestamp ns, GID) of an rmw_zenoh attachment; None if it is not one."""
    if len(data) != ATTACHMENT_SIZE or data[16] != GID_SIZE:
        return None
    seq, t_ns = struct.unpack_from("<qq", data)
    return seq, t_ns, bytes(data[17:])
