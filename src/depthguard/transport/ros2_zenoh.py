"""ROS 2 over Zenoh as ``rmw_zenoh_cpp`` speaks it: keys, attachment, liveliness tokens, one node (R31).

No ROS is needed: the CDR payloads are serialised by ``rosbags`` and the type hashes
computed by it (``Typestore.hash_rihs01``). The contract followed is that of
``ros2/rmw_zenoh`` for **Jazzy** (the ``jazzy`` branch, rmw_zenoh_cpp 0.2.x on zenoh 1.x;
Kilted and Rolling use the same wire format, read from the same sources:
``docs/design.md``, ``liveliness_utils.cpp``, ``attachment_helpers.cpp``, ``qos.cpp``):

- **Data key** of a topic: ``<domain>/<topic without its leading slash>/<DDS type name>/<type hash>``,
  e.g. ``0/chatter/std_msgs::msg::dds_::String_/RIHS01_df66...``; the DDS type name of
  ``pkg/msg/Name`` is ``pkg::msg::dds_::Name_``; the hash is ``RIHS01_`` + 64 hex digits.
- **Payload**: the message in CDR (little endian, 4-byte encapsulation header), as rosbags writes it.
- **Attachment** of every sample (33 bytes, zenoh-ext serialisation): sequence number int64 LE
  (from 1), source timestamp int64 LE (ns since the epoch), the publisher's GID as a
  length-prefixed byte sequence (LEB128 length 16, then 16 bytes). A rmw_zenoh subscription
  drops a sample without one.
- **Liveliness tokens** (``ros2 topic list``, ``ros2 node list``)::

      @ros2_lv/<domain>/<zid>/<nid>/<nid>/NN/<enclave>/<namespace>/<node>
      @ros2_lv/<domain>/<zid>/<nid>/<id>/MP|MS/<enclave>/<namespace>/<node>/<topic>/<type>/<hash>/<qos>

  ``/`` in a name is mangled to ``%`` (the root namespace and enclave ``/`` become ``%``); ids
  are one counter per session from 0; the QoS chunk leaves every value that equals
  rmw_zenoh's default empty (reliable, volatile, keep last, depth 42, infinite durations), so
  a reliable publisher of depth 10 is ``::,10:,:,:,,``.

Deliberate differences (``docs/ROS2.md``): the GID is the first 16 bytes of BLAKE2b of the
entity's token (rmw_zenoh uses XXH3-128 of it; the GID is opaque to subscribers); the
session is a Zenoh **client** of the cell's router (rmw_zenoh nodes are peers that the
router introduces to each other; a client reaches them through the router).
"""

from __future__ import annotations

import hashlib
import os
import re
import struct
import threading
import time
from collections import defaultdict
from typing import Callable

from rosbags.typesys import Stores, get_typestore

__all__ = ["Ros2Error", "WIRE", "ADMIN_SPACE", "DEFAULT_ROUTER", "GID_SIZE", "ATTACHMENT_SIZE", "HUMBLE_HASH",
           "check_topic", "dds_type_name", "type_hash", "topic_key", "topic_pattern", "split_key", "mangle",
           "qos_chunk", "node_token", "entity_token", "entity_gid", "encode_attachment", "decode_attachment",
           "default_domain", "Ros2Node", "node_for"]

#: the typestore of the wire: Jazzy's definitions (hashes and CDR)
WIRE = get_typestore(Stores.ROS2_JAZZY)
ADMIN_SPACE = "@ros2_lv"
DEFAULT_ROUTER = "tcp/127.0.0.1:7447"     # where `ros2 run rmw_zenoh_cpp rmw_zenohd` listens
GID_SIZE = 16                               # RMW_GID_STORAGE_SIZE since Iron
ATTACHMENT_SIZE = 8 + 8 + 1 + GID_SIZE
#: the hash chunk of a Humble rmw_zenoh key (Humble has no type hashes)
HUMBLE_HASH = "TypeHashNotSupported"
_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_MAX_DOMAIN = 232


class Ros2Error(ValueError):
    """A ROS 2 name, key, attachment or connection that cannot be used (one sentence why)."""


# ------------------------------------------------------------------ names and keys
def check_topic(name: str) -> str:
    """A fully qualified ROS 2 topic name (``/a/b``: tokens of letters, digits and ``_``, not
    starting with a digit); :class:`Ros2Error` otherwise."""
    if not isinstance(name, str) or not name.startswith("/") or name == "/":
        raise Ros2Error(f"topic {name!r} is not a fully qualified ROS 2 name (like /camera/depth/image_rect_raw)")
    for tok in name[1:].split("/"):
        if not _TOKEN.match(tok):
            raise Ros2Error(f"topic {name!r}: {tok!r} is not a ROS 2 name token (letters, digits, '_'; "
                            "not empty, not starting with a digit)")
    return name


def dds_type_name(msgtype: str) -> str:
    """``pkg/msg/Name`` -> ``pkg::msg::dds_::Name_`` (the type chunk of keys and tokens)."""
    parts = msgtype.split("/")
    if len(parts) != 3 or not all(parts):
        raise Ros2Error(f"message type {msgtype!r} is not pkg/msg/Name")
    return f"{parts[0]}::{parts[1]}::dds_::{parts[2]}_"


def type_hash(msgtype: str) -> str:
    """``RIHS01_<64 hex>`` of ``msgtype`` with Jazzy's definitions (rosbags' ``hash_rihs01``)."""
    return WIRE.hash_rihs01(msgtype)


def topic_key(domain: int, topic: str, msgtype: str) -> str:
    """The data key of ``topic`` carrying ``msgtype`` in ``domain`` (module docstring)."""
    return f"{int(domain)}/{check_topic(topic)[1:]}/{dds_type_name(msgtype)}/{type_hash(msgtype)}"


def topic_pattern(domain: int, topic: str) -> str:
    """The key expression of every type on ``topic`` (``*`` matches exactly one chunk, so no other topic)."""
    return f"{int(domain)}/{check_topic(topic)[1:]}/*/*"


def split_key(key: str) -> tuple[int, str, str, str]:
    """A data key -> ``(domain, "/topic", dds type name, hash)``."""
    parts = str(key).split("/")
    if len(parts) < 4 or not parts[0].isdigit():
        raise Ros2Error(f"key {key!r} is not <domain>/<topic>/<type>/<hash>")
    return int(parts[0]), "/" + "/".join(parts[1:-2]), parts[-2], parts[-1]


def mangle(name: str) -> str:
    """A name as one key chunk: ``/`` -> ``%`` (an empty name is ``%`` too)."""
    return name.replace("/", "%") if name else "%"


def qos_chunk(reliable: bool = True, transient_local: bool = False, depth: int = 10) -> str:
    """The QoS chunk of a token: ``<rel>:<dur>:<hist>,<depth>:<deadline s,ns>:<lifespan s,ns>:<liveliness,lease s,ns>``,
    a value equal to rmw_zenoh's default left empty (reliable 1, volatile 2, keep last 1, depth 42,
    infinite durations, automatic liveliness); best effort is 2, transient local 1 (``rmw/types.h``)."""
    if int(depth) < 1:
        raise Ros2Error(f"QoS depth must be >= 1 (got {depth})")
    rel = "" if reliable else "2"
    dur = "1" if transient_local else ""
    dep = "" if int(depth) == 42 else str(int(depth))
    return f"{rel}:{dur}:,{dep}:,:,:,,"


def node_token(domain: int, zid: str, nid: int, node: str, namespace: str = "/", enclave: str = "/") -> str:
    """The liveliness token of a node (``NN``; its id is repeated)."""
    return f"{ADMIN_SPACE}/{int(domain)}/{zid}/{nid}/{nid}/NN/{mangle(enclave)}/{mangle(namespace)}/{mangle(node)}"


def entity_token(domain: int, zid: str, nid: int, eid: int, kind: str, node: str, topic: str, msgtype: str,
                 qos: str, namespace: str = "/", enclave: str = "/") -> str:
    """The liveliness token of a publisher (``MP``) or subscription (``MS``) of ``node``."""
    if kind not in ("MP", "MS"):
        raise Ros2Error(f"entity kind {kind!r}: MP (publisher) or MS (subscription)")
    return (f"{ADMIN_SPACE}/{int(domain)}/{zid}/{nid}/{eid}/{kind}/{mangle(enclave)}/{mangle(namespace)}/"
            f"{mangle(node)}/{mangle(check_topic(topic))}/{dds_type_name(msgtype)}/{type_hash(msgtype)}/{qos}")


def entity_gid(token: str) -> bytes:
    """A 16-byte GID of the entity with liveliness token ``token`` (BLAKE2b; module docstring)."""
    return hashlib.blake2b(token.encode("utf-8"), digest_size=GID_SIZE).digest()


# ------------------------------------------------------------------ attachment
def encode_attachment(sequence: int, stamp_ns: int, gid: bytes) -> bytes:
    """The 33-byte attachment: int64 LE sequence, int64 LE source time (ns), LEB128 16 + GID."""
    if len(gid) != GID_SIZE:
        raise Ros2Error(f"a GID has {GID_SIZE} bytes (got {len(gid)})")
    return struct.pack("<qqB", int(sequence), int(stamp_ns), GID_SIZE) + bytes(gid)


def decode_attachment(raw: bytes) -> tuple[int, int, bytes]:
    """``(sequence, source time ns, gid)`` of an attachment; :class:`Ros2Error` for anything but
    two int64 and one length-prefixed GID of 16 bytes (Jazzy and later) or 24 (Humble)."""
    raw = bytes(raw)
    if len(raw) < 17:
        raise Ros2Error(f"attachment of {len(raw)} bytes: shorter than sequence + time + GID length")
    seq, stamp = struct.unpack_from("<qq", raw, 0)
    n, i, shift = 0, 16, 0
    while True:                                   # LEB128 length of the GID
        if i >= len(raw) or shift > 28:
            raise Ros2Error("attachment: the GID length is not a valid LEB128 number")
        b = raw[i]
        n |= (b & 0x7F) << shift
        i += 1
        shift += 7
        if not b & 0x80:
            break
    if n not in (16, 24) or len(raw) - i != n:
        raise Ros2Error(f"attachment: a GID of {n} bytes with {len(raw) - i} bytes left (expected 16, as "
                        f"{ATTACHMENT_SIZE} bytes in all)")
    return seq, stamp, raw[i:]


def default_domain() -> int:
    """``ROS_DOMAIN_ID`` of the environment, else 0."""
    text = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return 0
    if not text.isdigit():
        raise Ros2Error(f"ROS_DOMAIN_ID={text!r} is not a number")
    return int(text)


# ------------------------------------------------------------------ one node on one session
class Ros2Node:
    """One ROS 2 node (``NN`` token) on a Zenoh client session to the cell's router.

    ``publisher(topic, msgtype)`` / ``subscribe(topic, msgtype, fn)`` declare entities with their
    tokens. ``counts`` (reason -> number) and ``last_error`` collect what was received and
    not used, over every subscription of the node. Shared by the sources and the sink of a
    run (:func:`node_for`): each user calls :meth:`acquire` and :meth:`release`; the session
    closes with the last release.
    """

    def __init__(self, router: str = DEFAULT_ROUTER, domain: int = 0, name: str = "depthguard",
                 namespace: str = "/", connect_timeout_s: float = 5.0, session=None):
        if not isinstance(domain, int) or not 0 <= domain <= _MAX_DOMAIN:
            raise Ros2Error(f"ROS domain id {domain!r} must be an integer in 0..{_MAX_DOMAIN}")
        if not _TOKEN.match(name):
            raise Ros2Error(f"node name {name!r} is not a ROS 2 name token")
        if namespace != "/":
            check_topic(namespace)
        self.domain, self.name, self.namespace, self.router = domain, name, namespace, router
        self._own = session is None
        if session is None:
            session = _open_client(router, connect_timeout_s)
        self.session = session
        self.zid = str(session.info.zid())
        self._lock = threading.Lock()
        self._next_id = 0
        self.nid = self._take_id()
        self.token_key = node_token(domain, self.zid, self.nid, name, namespace)
        self._token = session.liveliness().declare_token(self.token_key)
        self._entities: list = []
        self.counts: dict[str, int] = defaultdict(int)
        self.last_error: str | None = None
        self._users = 0
        self.closed = False

    def _take_id(self) -> int:
        with self._lock:
            i = self._next_id
            self._next_id += 1
            return i

    def count(self, reason: str, sentence: str | None = None) -> None:
        with self._lock:
            self.counts[reason] += 1
            if sentence is not None:
                self.last_error = sentence

    def counters(self) -> dict:
        with self._lock:
            return dict(sorted(self.counts.items()))

    def publisher(self, topic: str, msgtype: str, depth: int = 10, transient_local: bool = False) -> "Ros2Publisher":
        return Ros2Publisher(self, topic, msgtype, depth, transient_local)

    def subscribe(self, topic: str, msgtype: str, fn: Callable, depth: int = 10) -> "Ros2Subscription":
        return Ros2Subscription(self, topic, msgtype, fn, depth)

    def acquire(self) -> "Ros2Node":
        with self._lock:
            self._users += 1
        return self

    def release(self) -> None:
        with self._lock:
            self._users -= 1
            last = self._users <= 0
        if last:
            self.close()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        for e in list(self._entities):
            e.close()
        _undeclare(self._token)
        if self._own:
            self.session.close()


def _undeclare(obj) -> None:
    try:
        obj.undeclare()
    except Exception:  # noqa: BLE001 - closing anyway (the session may be gone)
        pass


def _open_client(router: str, timeout_s: float):
    """A Zenoh client session connected to ``router`` (:class:`Ros2Error` when none answers)."""
    import zenoh

    from depthguard.transport.settings import zenoh_config

    try:
        cfg = zenoh_config(listen=(), connect=(router,))
    except ValueError as exc:
        raise Ros2Error(f"--ros2-router {router!r}: {exc}") from None
    cfg.insert_json5("mode", '"client"')
    cfg.insert_json5("connect/timeout_ms", str(int(timeout_s * 1000)))
    cfg.insert_json5("connect/exit_on_failure", "true")
    try:
        return zenoh.open(cfg)
    except Exception as exc:  # noqa: BLE001 - zenoh raises its own error type
        raise Ros2Error(f"no Zenoh router answers at {router} within {timeout_s:g} s ({exc}); start the cell's "
                        "router (`ros2 run rmw_zenoh_cpp rmw_zenohd`) or give --ros2-router") from None


#: the sporadic heartbeat of a reliable transient-local publisher (s), as rmw_zenoh's
#: ``SAMPLE_MISS_DETECTION_HEARTBEAT_PERIOD``
HEARTBEAT_S = 1.0


class Ros2Publisher:
    """A publisher (``MP`` token) of ``msgtype`` on ``topic``; :meth:`publish` sends a message with
    the attachment (sequence from 1, the wall time in ns, the GID).

    ``transient_local``: durability TRANSIENT_LOCAL as rmw_zenoh makes it
    (``rmw_publisher_data.cpp``): a zenoh-ext *advanced* publisher with publisher detection, a
    cache of the last ``depth`` samples (a late subscriber queries
    ``<key>/@adv/pub/<zid>/<eid>/...`` and gets them) and sample-miss detection by a sporadic
    heartbeat of :data:`HEARTBEAT_S`; the token's QoS chunk says durability ``1``.
    """

    def __init__(self, node: Ros2Node, topic: str, msgtype: str, depth: int = 10, transient_local: bool = False):
        self.node, self.topic, self.msgtype = node, check_topic(topic), msgtype
        self.transient_local = bool(transient_local)
        self.key = topic_key(node.domain, topic, msgtype)
        self.token_key = entity_token(node.domain, node.zid, node.nid, node._take_id(), "MP", node.name, topic,
                                      msgtype, qos_chunk(True, self.transient_local, depth), node.namespace)
        self.gid = entity_gid(self.token_key)
        self.sequence = 0
        if self.transient_local:
            import zenoh.ext as zext

            self._pub = zext.declare_advanced_publisher(
                node.session, self.key, cache=zext.CacheConfig(int(depth)), publisher_detection=True,
                sample_miss_detection=zext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=HEARTBEAT_S))
        else:
            self._pub = node.session.declare_publisher(self.key)
        self._token = node.session.liveliness().declare_token(self.token_key)
        node._entities.append(self)

    def publish_cdr(self, payload: bytes) -> None:
        self.sequence += 1
        self._pub.put(bytes(payload), attachment=encode_attachment(self.sequence, time.time_ns(), self.gid))

    def publish(self, msg) -> None:
        self.publish_cdr(bytes(WIRE.serialize_cdr(msg, self.msgtype)))

    def close(self) -> None:
        if self in self.node._entities:
            self.node._entities.remove(self)
            _undeclare(self._token)
            _undeclare(self._pub)


class Ros2Subscription:
    """A subscription (``MS`` token) to ``topic`` that calls ``fn(msg, stamp_ns)`` with every sample
    that carries ``msgtype`` and decodes; anything else is counted on the node, never raised:
    ``wrong_type:TOPIC`` (another type, or another definition of it), ``bad_attachment:TOPIC``,
    ``undecodable:TOPIC`` (garbage CDR), ``rejected:TOPIC`` (``fn`` raised ``ValueError``).

    It listens to every type on the topic (``topic_pattern``) so that a wrong type is seen and
    counted rather than silently never received. The expected hash is Jazzy's; a Humble
    publisher's ``TypeHashNotSupported`` is accepted for the types whose Humble and Jazzy
    definitions are the same (checked when the subscription is made).
    """

    def __init__(self, node: Ros2Node, topic: str, msgtype: str, fn: Callable, depth: int = 10):
        from depthguard.transport import ros_messages as rosmsg

        self.node, self.topic, self.msgtype, self.fn = node, check_topic(topic), msgtype, fn
        self.dds, self.hash = dds_type_name(msgtype), type_hash(msgtype)
        self._hashes = {self.hash} | ({HUMBLE_HASH} if rosmsg.TYPESTORE.hash_rihs01(msgtype) == self.hash else set())
        self.token_key = entity_token(node.domain, node.zid, node.nid, node._take_id(), "MS", node.name, topic,
                                      msgtype, qos_chunk(True, False, depth), node.namespace)
        self.received = 0
        self._sub = node.session.declare_subscriber(topic_pattern(node.domain, topic), self._on_sample)
        self._token = node.session.liveliness().declare_token(self.token_key)
        node._entities.append(self)

    def _on_sample(self, sample) -> None:
        key = str(sample.key_expr)
        try:
            _d, _t, dds, h = split_key(key)
            if dds != self.dds or h not in self._hashes:
                self.node.count(f"wrong_type:{self.topic}", f"{key}: expected {self.dds}/{self.hash} on {self.topic}")
                return
            if sample.attachment is None:
                self.node.count(f"bad_attachment:{self.topic}", f"{key}: a sample without the rmw_zenoh attachment")
                return
            _seq, stamp_ns, _gid = decode_attachment(sample.attachment.to_bytes())
        except Ros2Error as exc:
            self.node.count(f"bad_attachment:{self.topic}", f"{key}: {exc}")
            return
        try:
            msg = WIRE.deserialize_cdr(sample.payload.to_bytes(), self.msgtype)
        except Exception as exc:  # noqa: BLE001 - garbage CDR raises many kinds of errors: counted, never a crash
            self.node.count(f"undecodable:{self.topic}", f"{key}: the payload is not a {self.msgtype} in CDR "
                                                         f"({type(exc).__name__}: {exc})")
            return
        self.received += 1
        try:
            self.fn(msg, stamp_ns)
        except ValueError as exc:
            self.node.count(f"rejected:{self.topic}", f"{self.topic}: {exc}")
        except Exception as exc:  # noqa: BLE001 - a message that breaks a handler is counted, never a crash
            self.node.count(f"rejected:{self.topic}", f"{self.topic}: {type(exc).__name__}: {exc}")

    def close(self) -> None:
        if self in self.node._entities:
            self.node._entities.remove(self)
            _undeclare(self._token)
            _undeclare(self._sub)


def node_for(context: dict) -> Ros2Node:
    """The run's node (``context["ros2_node"]``), opened on first use from ``context["ros2_router"]``
    (default :data:`DEFAULT_ROUTER`) and ``context["ros2_domain"]`` (default ``ROS_DOMAIN_ID`` or 0);
    the caller owns one :meth:`~Ros2Node.acquire` and must :meth:`~Ros2Node.release` it."""
    node = context.get("ros2_node")
    if node is None or node.closed:
        domain = context.get("ros2_domain")
        node = Ros2Node(router=context.get("ros2_router") or DEFAULT_ROUTER,
                        domain=default_domain() if domain is None else domain,
                        session=context.get("ros2_session"))
        context["ros2_node"] = node
    return node.acquire()
