"""The monitor's results as an MCAP file beside the input: ``monitor --out DIR`` writes
``DIR/results.mcap`` (R31).

A sink (``sink(reaction)``, ``close()``) that writes ROS 2 CDR messages, with their
definitions embedded as ROS 2 bags do, so that Foxglove (or any MCAP reader) opens the
results beside the input bag on the same clock — the reaction time ``t`` is the
header stamp and the log time (the input's header stamps are on that clock too):

- ``/depthguard/reaction`` — ``depthguard_msgs/msg/Reaction`` (:data:`REACTION_MSG`), every
  cycle: the whole record of the log. "Nothing within rho" (``within_rho`` false, observed)
  and "cannot judge" (``observed`` false) are separate fields, never one number;
- ``/depthguard/override`` — ``std_msgs/msg/Float64``, every cycle (0 = stop);
- ``/depthguard/obstacles`` — ``sensor_msgs/msg/PointCloud2``, at every free-space map update
  (``monitor: free_space: true``; :meth:`McapResults.write_map`): the occupied and unknown voxels,
  the robot removed, with a ``state`` field (1 unknown, 2 occupied; :mod:`depthguard.runtime.map_cloud`);
- ``/depthguard/markers`` — ``visualization_msgs/msg/MarkerArray`` in frame ``world``, at most
  ``marker_hz`` times per second of run time: a sphere per control point (green: nothing
  within rho; orange: an obstacle within rho; grey: cannot judge) and an arrow from the
  point to its nearest obstacle (length = the distance).

The file is written as a rosbag2 directory ``DIR/.results.mcap.partial/`` while the run lasts
(zstd chunks) and moved to ``DIR/results.mcap`` at :meth:`McapResults.close`; an existing
``results.mcap`` is never overwritten.
"""

from __future__ import annotations

import math
import os
import shutil
import struct
import threading
from dataclasses import replace
from pathlib import Path

import numpy as np

from depthguard.runtime.reaction_cdr import float64_cdr, markers_cdr
from depthguard.runtime.reaction_cdr_fill import reaction_cdr_filled
from depthguard.transport import ros_messages as rosmsg

__all__ = ["McapResults", "REACTION_MSG", "REACTION_TYPE", "TOPICS"]

REACTION_TYPE = "depthguard_msgs/msg/Reaction"
REACTION_MSG = """\
std_msgs/Header header
float64 override
geometry_msgs/Vector3 repulsion
float64[] qd_min
float64[] qd_max
string[] names
bool[] watch
bool[] observed
bool[] within_rho
float64[] distance
geometry_msgs/Vector3[] direction
string[] reason_keys
string[] reason_texts
string[] cameras
string[] camera_states
float64[] camera_age_s
float64 joints_age_s
float64[] q
"""
TOPICS = {"reaction": "/depthguard/reaction", "override": "/depthguard/override", "markers": "/depthguard/markers",
          "obstacles": "/depthguard/obstacles"}

_registered = False


def _register() -> None:
    global _registered
    if not _registered:
        from rosbags.typesys import get_types_from_msg

        rosmsg.TYPESTORE.register(get_types_from_msg(REACTION_MSG, REACTION_TYPE))
        _registered = True


def _age(x: float) -> float:
    return float(x) if math.isfinite(x) else -1.0          # -1 = nothing yet


#: an MCAP Message record's head: opcode 0x05, record length, channel id, sequence 0, log and publish time
_MESSAGE = struct.Struct("<BQHIQQ")
_CHUNK_BYTES = 2**20                # rosbags' McapWriter closes its chunk past this many bytes


class _Appender:
    """``append(connection, ns, data)``: what ``rosbags.rosbag2.Writer.write`` does for a bag on
    MCAP storage compressed per chunk (issue 29): the same Message record into the open chunk,
    the same counters (the writer's counts and time range, the storage's channel statistics,
    the chunk's time range and message index), and the chunk closed by its own
    ``close_chunk`` at the same size, in a few Python steps instead of ~25 us a message. Any
    other writer (per-message compression, another storage, a rosbags whose writer lacks
    these fields) is written through ``Writer.write`` itself. ``tests/test_runtime_sinks.py``
    holds the files byte for byte equal."""

    def __init__(self, writer):
        self.writer = writer
        self.fast = False
        try:
            from rosbags.rosbag2.enums import CompressionMode
            from rosbags.rosbag2.storage_mcap import McapWriter, PendingChunk

            st = writer.storage
            self.fast = (type(st) is McapWriter and writer.compression_mode != CompressionMode.MESSAGE
                         and type(st.chunk) is PendingChunk and isinstance(writer.counts, dict)
                         and isinstance(st.channel_stats, dict)
                         and all(hasattr(x, a) for x, a in ((writer, "min_timestamp"), (writer, "max_timestamp"),
                                                            (st, "message_start_time"), (st, "message_end_time"),
                                                            (st, "close_chunk"))))
        except Exception:  # noqa: BLE001 - another rosbags: its own write
            self.fast = False

    def append(self, con, ns: int, data: bytes) -> None:
        w = self.writer
        if not self.fast:
            w.write(con, ns, data)
            return
        if con not in w.connections:
            w.write(con, ns, data)              # its error
            return
        st = w.storage
        ch = st.chunk
        cid = con.id
        if ns < st.message_start_time:
            st.message_start_time = ns
        if ns > st.message_end_time:
            st.message_end_time = ns
        st.channel_stats[cid] += 1
        if ns < ch.message_start_time:
            ch.message_start_time = ns
        if ns > ch.message_end_time:
            ch.message_end_time = ns
        bio = ch.bio
        ch.msgs[cid].append((ns, bio.tell()))
        bio.write(_MESSAGE.pack(0x05, 22 + len(data), cid, 0, ns, ns))
        bio.write(data)
        if bio.tell() > _CHUNK_BYTES:
            st.close_chunk()
        w.counts[cid] += 1
        if ns < w.min_timestamp:
            w.min_timestamp = ns
        if ns > w.max_timestamp:
            w.max_timestamp = ns


class McapResults:
    """Sink writing ``results.mcap`` (module docstring); ``robot`` places the control points
    (``control_point_positions(q)``), ``watch_points`` are ``(name, (3,) m)`` of the config."""

    def __init__(self, path: str | Path, robot, watch_points=(), marker_hz: float = 30.0, frame_id: str = "world"):
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

        _register()
        self.path = Path(path)
        if self.path.exists():
            raise ValueError(f"{self.path} exists already (a run never overwrites one); choose a new folder")
        self._tmp = self.path.parent / f".{self.path.name}.partial"
        if self._tmp.exists():
            raise ValueError(f"{self._tmp} exists (left by an interrupted run); remove it or choose a new folder")
        self.robot = robot
        self._watch = {n: np.asarray(p, dtype=np.float64) for n, p in watch_points}
        self.frame_id = frame_id
        self.period = 1.0 / float(marker_hz)
        self._next_marker = -math.inf
        self._writer = Writer(self._tmp, version=9, storage_plugin=StoragePlugin.MCAP)
        self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        self._writer.open()
        ts = rosmsg.TYPESTORE
        self._con = {"reaction": self._writer.add_connection(TOPICS["reaction"], REACTION_TYPE, typestore=ts),
                     "override": self._writer.add_connection(TOPICS["override"], rosmsg.MSG["Float64"], typestore=ts),
                     "markers": self._writer.add_connection(TOPICS["markers"], rosmsg.MSG["MarkerArray"], typestore=ts),
                     "obstacles": self._writer.add_connection(TOPICS["obstacles"], "sensor_msgs/msg/PointCloud2",
                                                              typestore=ts)}
        self.written = 0
        self._append = _Appender(self._writer).append
        self._lock = threading.Lock()      # the map's thread writes too (write_map)
        self._warm_up()

    def _warm_up(self) -> None:
        """Serialise (and drop) one message of each topic's type: the CDR serialiser of a type is
        generated on its first use, 37 ms under the GIL that held up every thread of a real-time
        run in its first cycles (the simulated cameras fell behind the clock there)."""
        from types import SimpleNamespace

        q = np.asarray(self.robot.q_home, dtype=np.float64)
        m = len(self.robot.control_points)
        r = SimpleNamespace(t=0.0, override=0.0, repulsion=np.zeros(3), qd_min=np.zeros(len(q)),
                            qd_max=np.zeros(len(q)), names=[cp.name for cp in self.robot.control_points],
                            is_watch=np.zeros(m, dtype=bool), observed=np.ones(m, dtype=bool),
                            distance=np.full(m, 0.1), direction=np.tile([0.0, 0.0, 1.0], (m, 1)),
                            reasons={"warm-up": "not written"}, cameras={}, joints_age_s=0.0, q=q)
        T = rosmsg.TYPESTORE.types
        for msg in (self.reaction_msg(r), T[rosmsg.MSG["Float64"]](data=0.0), self.markers_msg(r)):
            rosmsg.serialize(msg)
        reaction_cdr_filled(r, self.frame_id)      # its kernel compiled or loaded (numba) here too

    # ------------------------------------------------------------ messages
    def reaction_msg(self, r):
        T = rosmsg.TYPESTORE.types
        vec = T["geometry_msgs/msg/Vector3"]
        within = np.isfinite(r.distance)
        cams = list(r.cameras)
        return T[REACTION_TYPE](
            header=rosmsg.header(r.t, self.frame_id), override=float(r.override),
            repulsion=vec(x=float(r.repulsion[0]), y=float(r.repulsion[1]), z=float(r.repulsion[2])),
            qd_min=np.asarray(r.qd_min, dtype=np.float64), qd_max=np.asarray(r.qd_max, dtype=np.float64),
            names=list(r.names), watch=np.asarray(r.is_watch, dtype=bool), observed=np.asarray(r.observed, dtype=bool),
            within_rho=within.astype(bool), distance=np.where(within, r.distance, 0.0).astype(np.float64),
            direction=[vec(x=float(d[0]), y=float(d[1]), z=float(d[2])) if w else vec(x=0.0, y=0.0, z=0.0)
                       for d, w in zip(r.direction, within)],
            reason_keys=list(r.reasons), reason_texts=list(r.reasons.values()), cameras=cams,
            camera_states=[r.cameras[c].state for c in cams],
            camera_age_s=np.array([_age(r.cameras[c].age_s) for c in cams], dtype=np.float64),
            joints_age_s=_age(r.joints_age_s), q=np.asarray(r.q, dtype=np.float64))

    def _marker_points(self, r):
        """``(n_cp, positions, sizes)``: the number of control points (the first ones), each
        point's marker position ((3,) m: a control point's at ``r.q``, a watch point's own)
        and its sphere's diameter (m)."""
        n_cp = int(np.count_nonzero(~np.asarray(r.is_watch)))
        pts = np.asarray(self.robot.control_point_positions(r.q), dtype=np.float64)[:n_cp] if n_cp else np.zeros((0, 3))
        radii = [max(2.0 * float(cp.radius), 0.03) for cp in self.robot.control_points][:n_cp]
        positions, sizes = list(pts), list(radii)
        for name in r.names[n_cp:]:
            positions.append(self._watch.get(name, np.zeros(3)))
            sizes.append(0.05)
        return n_cp, positions, sizes

    def markers_cdr(self, r) -> bytes:
        """The bytes of ``rosmsg.serialize(self.markers_msg(r))``, written directly
        (:func:`~depthguard.runtime.reaction_cdr.markers_cdr`)."""
        n_cp, positions, sizes = self._marker_points(r)
        return markers_cdr(r.t, self.frame_id, r.names, n_cp, np.reshape(positions, (-1, 3)), sizes, r.observed,
                           r.distance, r.direction)

    def markers_msg(self, r):
        T = rosmsg.TYPESTORE.types
        marker, point = T["visualization_msgs/msg/Marker"], T["geometry_msgs/msg/Point"]
        pose = T["geometry_msgs/msg/Pose"](position=point(x=0.0, y=0.0, z=0.0),
                                          orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))
        color = T["std_msgs/msg/ColorRGBA"]
        hdr = rosmsg.header(r.t, self.frame_id)
        n_cp, positions, sizes = self._marker_points(r)

        def make(i, kind, ns, pos, scale, rgba, points=()):
            return marker(header=hdr, ns=ns, id=i, type=kind, action=0,
                          pose=T["geometry_msgs/msg/Pose"](position=point(x=float(pos[0]), y=float(pos[1]), z=float(pos[2])),
                                                           orientation=pose.orientation),
                          scale=T["geometry_msgs/msg/Vector3"](x=scale[0], y=scale[1], z=scale[2]),
                          color=color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]),
                          lifetime=T["builtin_interfaces/msg/Duration"](sec=0, nanosec=0), frame_locked=False,
                          points=[point(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in points], colors=[],
                          texture_resource="", texture=T["sensor_msgs/msg/CompressedImage"](
                              header=hdr, format="", data=np.zeros(0, dtype=np.uint8)),
                          uv_coordinates=[], text="", mesh_resource="",
                          mesh_file=T["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, dtype=np.uint8)),
                          mesh_use_embedded_materials=False)

        out = [replace(make(0, 0, "", (0, 0, 0), (0.0, 0.0, 0.0), (0, 0, 0, 0)), action=3)]   # DELETEALL first
        for i, (name, p, s) in enumerate(zip(r.names, positions, sizes)):
            obs, d = bool(r.observed[i]), float(r.distance[i])
            rgba = (0.6, 0.6, 0.6, 0.8) if not obs else ((1.0, 0.5, 0.0, 0.9) if math.isfinite(d) else (0.1, 0.8, 0.2, 0.8))
            out.append(make(i, 2, "control_points" if i < n_cp else "watch_points", p, (s, s, s), rgba))  # SPHERE
            if obs and math.isfinite(d):
                end = np.asarray(p) + d * np.asarray(r.direction[i], dtype=np.float64)
                out.append(make(i, 0, "distance", (0, 0, 0), (0.01, 0.02, 0.03), (1.0, 0.2, 0.1, 1.0), [p, end]))  # ARROW
        return T[rosmsg.MSG["MarkerArray"]](markers=out)

    # ------------------------------------------------------------ sink
    def __call__(self, r) -> None:
        if self._writer is None:
            raise ValueError(f"{self.path}: closed")
        if not (math.isfinite(r.t) and r.t >= 0):
            return                                  # a ROS time cannot hold it (never on the monitor's clocks)
        ns = int(round(r.t * 1e9))                 # rosmsg.stamp_ns(r.t) for a finite t >= 0, without its message
        # the bytes rosbags serialises from reaction_msg(r) and a Float64, written directly (issue 29)
        reaction, override = reaction_cdr_filled(r, self.frame_id), float64_cdr(r.override)
        append, con = self._append, self._con
        with self._lock:
            if self._writer is None:
                raise ValueError(f"{self.path}: closed")
            append(con["reaction"], ns, reaction)
            append(con["override"], ns, override)
            if r.t >= self._next_marker:
                append(con["markers"], ns, self.markers_cdr(r))
                self._next_marker = r.t + self.period - 1e-9
        self.written += 1

    def write_map(self, snapshot) -> None:
        """The free-space map's occupied and unknown voxels, the robot removed, as a
        ``sensor_msgs/PointCloud2`` on ``/depthguard/obstacles`` at the map's newest capture
        stamp (:mod:`depthguard.runtime.map_cloud`); a map without a stamp is not written."""
        from depthguard.runtime.map_cloud import obstacle_cloud

        if self._writer is None:
            raise ValueError(f"{self.path}: closed")
        if not (math.isfinite(snapshot.stamp) and snapshot.stamp >= 0):
            return
        data = rosmsg.serialize(obstacle_cloud(snapshot, snapshot.stamp, self.frame_id))
        with self._lock:
            if self._writer is not None:
                self._append(self._con["obstacles"], rosmsg.stamp_ns(snapshot.stamp), data)

    def close(self) -> None:
        """Finish the file and move it to ``path`` (the partial directory is removed)."""
        with self._lock:
            if self._writer is None:
                return
            self._writer.close()
            self._writer = None
        inner = self._tmp / f"{self._tmp.name}.mcap"
        if self.path.exists():
            raise ValueError(f"{self.path} appeared during the run; the results stay in {inner}")
        os.replace(inner, self.path)
        shutil.rmtree(self._tmp, ignore_errors=True)


def open_mcap(argument: str, rig, context: dict) -> McapResults:
    """``mcap:[FILE]`` (:mod:`depthguard.runtime.sink_specs`): default ``OUT/results.mcap``."""
    from depthguard.runtime.sinks import run_file

    return McapResults(run_file(argument, context, "results.mcap", "mcap"), rig.robot,
                       [(w.name, w.position) for w in rig.monitor.watch_points])
