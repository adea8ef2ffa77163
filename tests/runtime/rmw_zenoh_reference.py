"""An rmw_zenoh reader written from rmw_zenoh's design document (ros2/rmw_zenoh `docs/design.md`,
sections "Topic and Service name mapping to Zenoh key expressions", "Graph Cache", "Publishers"),
independent of `litevloc.runtime.transport.rmw_zenoh`: the tests parse what LiteVLoc puts on Zenoh with it.

Reference type hashes (RIHS01, REP-2011) as ROS 2 itself generated them: the `type_hashes`
entries of the type-description files that `rosidl_generator_type_description` installs with a
ROS 2 Jazzy build (`/opt/ros/jazzy/share/<package>/msg/<Type>.json`), read from the public
repository ruredot/opt-ros-jazzy-share at commit 28471ab6622322562a010932b6af1fad60f3e8a7
(`share/<package>/msg/<Type>.json`). The std_msgs/String value is also the one quoted in
rmw_zenoh's design document (the `chatter` examples).

ROS 2 Humble (`distro="humble"`), read from rmw_zenoh's Humble release sources
(ros2-gbp/rmw_zenoh-release, branch `release/humble/rmw_zenoh_cpp`, 0.1.9): `src/detail/
rmw_publisher_data.cpp` and `rmw_subscription_data.cpp` pass the constant `TypeHashNotSupported`
where Jazzy passes the RIHS01 string; `liveliness_utils.cpp` (`TopicInfo`, `Entity`) builds keys
and tokens from it exactly as Jazzy's does, and `attachment_helpers.cpp` writes the same fields
(the GID fixed at 16 bytes).
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass

REFERENCE_HASHES = {
    "std_msgs/msg/String": "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "nav_msgs/msg/Odometry": "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
    "geometry_msgs/msg/PoseStamped": "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8",
    "geometry_msgs/msg/PoseWithCovarianceStamped":
        "RIHS01_26432f9803e43727d3c8f668d1fdb3c630f548af631e2f4e31382371bfea3b6e",
    "geometry_msgs/msg/TransformStamped": "RIHS01_0a241f87d04668d94099cbb5ba11691d5ad32c2f29682e4eb5653424bd275206",
    "tf2_msgs/msg/TFMessage": "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    "diagnostic_msgs/msg/DiagnosticArray": "RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e",
    "sensor_msgs/msg/Image": "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47",
    "sensor_msgs/msg/CompressedImage": "RIHS01_15640771531571185e2efc8a100baf923961a4d15d5569652e6cb6691e8e371a",
}

# design document examples (verbatim), used to check this reader itself
DOC_TOPIC_KEY = ("0/robot1/chatter/std_msgs::msg::dds_::String_/"
                 "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18")
DOC_NODE_TOKEN = "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
DOC_PUB_TOKEN = ("@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/"
                 "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,7:,:,:,,")

HUMBLE_TYPE_HASH = "TypeHashNotSupported"

_DDS = re.compile(r"^([A-Za-z0-9_]+)::msg::dds_::([A-Za-z0-9_]+)_$")
_HASH = re.compile(r"^RIHS01_[0-9a-f]{64}$")


def check_type_hash(chunk: str, distro: str) -> None:
    """The type hash chunk of a key or token is of `distro`'s form ("jazzy": RIHS01, "humble")."""
    if distro == "humble":
        assert chunk == HUMBLE_TYPE_HASH, chunk
    else:
        assert distro == "jazzy" and _HASH.match(chunk), (distro, chunk)


def ros_type(dds_name: str) -> str:
    """`pkg::msg::dds_::Name_` -> `pkg/msg/Name`."""
    m = _DDS.match(dds_name)
    assert m, f"not a DDS type name: {dds_name!r}"
    return f"{m.group(1)}/msg/{m.group(2)}"


@dataclass(frozen=True)
class DataKey:
    domain_id: int
    topic: str  # fully qualified, with the leading '/'
    type: str  # ROS type name
    type_hash: str


def parse_data_key(key: str, distro: str = "jazzy") -> DataKey:
    """`<domain_id>/<fully qualified name>/<type name>/<type hash>`."""
    parts = key.split("/")
    assert len(parts) >= 4, key
    check_type_hash(parts[-1], distro)
    return DataKey(int(parts[0]), "/" + "/".join(parts[1:-2]), ros_type(parts[-2]), parts[-1])


@dataclass(frozen=True)
class QosText:
    reliability: int  # rmw enumerators; 0 where the token left it at rmw_zenoh's default
    durability: int
    history: int
    depth: int


@dataclass(frozen=True)
class Token:
    domain_id: int
    zid: str
    node_id: int
    entity_id: int
    kind: str
    enclave: str
    namespace: str
    node_name: str
    topic: str | None = None
    type: str | None = None
    type_hash: str | None = None
    qos: QosText | None = None


def _demangle(s: str) -> str:
    return s.replace("%", "/")


def parse_qos(text: str) -> QosText:
    """`<rel>:<dur>:<hist>,<depth>:<deadline s,ns>:<lifespan s,ns>:<liveliness,lease s,ns>`; an empty
    field is rmw_zenoh's default (RELIABLE=1, VOLATILE=2, KEEP_LAST=1, depth 42)."""
    f = text.split(":")
    assert len(f) == 6, text
    hist, depth = f[2].split(",")
    assert f[3] == "," and f[4] == "," and f[5] == ",,", f"deadline/lifespan/liveliness not default: {text}"
    return QosText(int(f[0] or 1), int(f[1] or 2), int(hist or 1), int(depth or 42))


def parse_token(key: str, distro: str = "jazzy") -> Token:
    """A node (`NN`) or publisher/subscription (`MP`/`MS`) liveliness token of `distro`."""
    p = key.split("/")
    assert p[0] == "@ros2_lv", key
    kind = p[5]
    assert kind in ("NN", "MP", "MS", "SS", "SC"), key
    base = dict(domain_id=int(p[1]), zid=p[2], node_id=int(p[3]), entity_id=int(p[4]), kind=kind,
                enclave=_demangle(p[6]), namespace=_demangle(p[7]), node_name=p[8])
    if kind == "NN":
        assert len(p) == 9, key
        return Token(**base)  # type: ignore[arg-type]
    assert len(p) == 13, key
    check_type_hash(p[11], distro)
    return Token(**base, topic=_demangle(p[9]), type=ros_type(p[10]), type_hash=p[11],  # type: ignore[arg-type]
                 qos=parse_qos(p[12]))


def parse_attachment(data: bytes) -> tuple[int, int, bytes]:
    """(sequence number, source timestamp ns since the epoch, GID): int64 LE, int64 LE, 1-byte GID
    length (16), the GID."""
    assert len(data) == 8 + 8 + 1 + 16, len(data)
    seq, ts = struct.unpack("<qq", data[:16])
    assert data[16] == 16
    return seq, ts, data[17:]
