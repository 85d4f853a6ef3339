"""The monitor's reactions as live ROS 2 topics, through Zenoh (``monitor --ros2``) (R29, R31).

A sink (``sink(reaction)``, ``close()``) that publishes, as the node ``/depthguard`` on
the cell's rmw_zenoh network (wire contract: :mod:`depthguard.transport.ros2_zenoh`), under a
namespace (default ``/depthguard``):

- ``<ns>/override`` — ``std_msgs/msg/Float64``, every control cycle: the speed override in
  [0, 1], 0 = stop (a robot driver scales its commanded speed by it);
- ``<ns>/reaction`` — ``depthguard_msgs/msg/Reaction`` (the definition of
  :data:`~depthguard.runtime.mcap_results.REACTION_MSG`), every cycle: the whole record, where
  "nothing within rho" (``within_rho`` false, ``observed`` true) and "cannot judge"
  (``observed`` false) are separate fields. A ROS node decodes it with a package holding
  that ``.msg`` (its RIHS01 hash is in the key);
- ``<ns>/markers`` — ``visualization_msgs/msg/MarkerArray`` at most ``marker_hz`` times per
  second of run time, the markers of ``results.mcap`` (green / orange / grey spheres, arrows
  to the nearest obstacles) for RViz or Foxglove.
- ``scaling_topic`` (default ``/joint_trajectory_controller/speed_scaling_input``, ``None``: not
  published) — ``control_msgs/msg/SpeedScalingFactor`` (``float64 factor``, the definition kept
  here: :data:`SCALING_MSG`), every cycle: the reaction's ``speed_scale`` in [0, 1] (the
  override, times the SSM scale in ``ssm``/``both`` modes), the speed scaling input of the
  ros2_control ``joint_trajectory_controller`` (Kilted and later: its ``~/speed_scaling_input``,
  0 = the trajectory halts on its path). Reliable, TRANSIENT_LOCAL, depth 1, as the controller
  subscribes to it: a controller that (re)starts gets the newest factor at once.
- ``<ns>/obstacles`` — ``sensor_msgs/msg/PointCloud2`` at every free-space map update of a run
  with the map on (:meth:`Ros2Sink.write_map`; R37, issue 30 "the map out"): the message of
  :func:`~depthguard.runtime.map_cloud.obstacle_cloud` (occupied and unknown voxel centres, the
  robot removed, field ``state`` 1 unknown / 2 occupied), stamped with the map's newest capture
  stamp. Reliable, VOLATILE, keep last 1: a planner wants the newest map only, and a late
  subscriber waits for the next update (at most 1 / ``free_space_hz`` s). Declared at the first
  map, so a run without the map has no such publisher.
- ``<ns>/check_path/request`` → ``<ns>/check_path/verdict`` — once the sink is attached to the
  run's monitor (:meth:`Ros2Sink.attach`, as ``depthguard monitor`` does): a planned
  ``trajectory_msgs/JointTrajectory`` in, the ``check-path --json`` verdict out as
  ``std_msgs/String`` (:mod:`depthguard.runtime.ros2_path_checks`).

Header stamps are the reaction time ``t`` (the wall clock in a live run). The messages are
built by :class:`~depthguard.runtime.mcap_results.McapResults`' own functions, so the live
topics and ``results.mcap`` carry the same values.
"""

from __future__ import annotations

import math
import threading

from depthguard.transport.ros2_zenoh import WIRE, Ros2Error, check_topic

__all__ = ["Ros2Sink", "open_ros2_sink", "DEFAULT_NAMESPACE", "DEFAULT_SCALING_TOPIC", "SCALING_TYPE", "SCALING_MSG"]

DEFAULT_NAMESPACE = "/depthguard"
#: ``~/speed_scaling_input`` of a joint_trajectory_controller named ``joint_trajectory_controller``
DEFAULT_SCALING_TOPIC = "/joint_trajectory_controller/speed_scaling_input"
SCALING_TYPE = "control_msgs/msg/SpeedScalingFactor"
#: control_msgs' SpeedScalingFactor.msg (ros-controls/control_msgs, Kilted and later)
SCALING_MSG = "float64 factor\n"
OBSTACLES_TYPE = "sensor_msgs/msg/PointCloud2"


class _Messages:
    """The message builders of ``McapResults`` without its file: they read only ``robot``,
    ``_watch``, ``frame_id`` and ``McapResults._marker_points``."""

    def __init__(self, robot, watch_points, frame_id: str):
        import numpy as np

        from depthguard.runtime.mcap_results import McapResults, _register

        _register()                          # depthguard_msgs/msg/Reaction in the messages' typestore
        self.robot, self.frame_id = robot, frame_id
        self._watch = {n: np.asarray(p, dtype=np.float64) for n, p in watch_points}
        self.reaction = McapResults.reaction_msg.__get__(self)
        self._marker_points = McapResults._marker_points.__get__(self)    # what markers_msg calls
        self.markers = McapResults.markers_msg.__get__(self)


def _register_wire() -> None:
    from depthguard.runtime.mcap_results import REACTION_MSG, REACTION_TYPE

    if REACTION_TYPE not in WIRE.fielddefs:
        from rosbags.typesys import get_types_from_msg

        WIRE.register(get_types_from_msg(REACTION_MSG, REACTION_TYPE))
    if SCALING_TYPE not in WIRE.fielddefs:
        from rosbags.typesys import get_types_from_msg

        WIRE.register(get_types_from_msg(SCALING_MSG, SCALING_TYPE))


class Ros2Sink:
    """Publishes reactions on ``<namespace>/{override,reaction,markers}`` and ``scaling_topic`` (module docstring).

    ``node``: an acquired :class:`~depthguard.transport.ros2_zenoh.Ros2Node` (released at
    :meth:`close`); ``robot`` places the control points; ``watch_points``: ``(name, (3,) m)``.
    ``published``: reactions sent.
    """

    name = "ros2"

    def __init__(self, node, robot, watch_points=(), namespace: str = DEFAULT_NAMESPACE, marker_hz: float = 30.0,
                 frame_id: str = "world", scaling_topic: str | None = DEFAULT_SCALING_TOPIC):
        from depthguard.runtime.mcap_results import REACTION_TYPE
        from depthguard.transport import ros_messages as rosmsg

        self.node = node
        self._map_lock = threading.Lock()      # the map's thread calls write_map
        self._map_pub = None
        self.maps_published = 0
        self.path_checks = None                # attach(monitor): check_path over ROS 2
        try:
            if not marker_hz > 0:
                raise Ros2Error(f"marker rate must be > 0 Hz (got {marker_hz})")
            ns = check_topic(namespace).rstrip("/")
            self.namespace = ns
            _register_wire()
            self._msgs = _Messages(robot, watch_points, frame_id)
            self.topics = {"override": f"{ns}/override", "reaction": f"{ns}/reaction", "markers": f"{ns}/markers"}
            self.map_topic = f"{ns}/obstacles"
            types = {"override": rosmsg.MSG["Float64"], "reaction": REACTION_TYPE, "markers": rosmsg.MSG["MarkerArray"]}
            if scaling_topic is not None:
                self.topics["scaling"] = check_topic(scaling_topic)
                types["scaling"] = SCALING_TYPE
            self._pubs = {k: node.publisher(t, types[k], **({"depth": 1, "transient_local": True} if k == "scaling"
                                                             else {}))
                          for k, t in self.topics.items()}
        except Exception:
            node.release()
            raise
        self._float64 = rosmsg.TYPESTORE.types[rosmsg.MSG["Float64"]]
        self._scaling = WIRE.types[SCALING_TYPE]
        self.period = 1.0 / float(marker_hz)
        self._next_marker = -math.inf
        self.published = 0

    def __call__(self, r) -> None:
        if self._pubs is None:
            raise Ros2Error("the ROS 2 sink is closed")
        if not (math.isfinite(r.t) and r.t >= 0):
            return                                  # a ROS time cannot hold it (never on the monitor's clocks)
        self._pubs["override"].publish(self._float64(data=float(r.override)))
        self._pubs["reaction"].publish(self._msgs.reaction(r))
        if "scaling" in self._pubs:
            self._pubs["scaling"].publish(self._scaling(factor=min(max(float(r.speed_scale), 0.0), 1.0)))
        if r.t >= self._next_marker:
            self._pubs["markers"].publish(self._msgs.markers(r))
            self._next_marker = r.t + self.period - 1e-9
        self.published += 1

    def attach(self, monitor) -> None:
        """Answer ``<ns>/check_path/request`` with ``monitor``'s path check (R22, R37;
        :class:`~depthguard.runtime.ros2_path_checks.Ros2PathChecks` on this sink's node, closed
        with the sink). A monitor without a robot has no path to check: nothing is declared."""
        from depthguard.runtime.ros2_path_checks import Ros2PathChecks

        if self.path_checks is None and self._pubs is not None and getattr(monitor, "robot", None) is not None:
            self.path_checks = Ros2PathChecks(self.node.acquire(), monitor, self.namespace)

    def write_map(self, snapshot) -> None:
        """R37: the free-space map ``snapshot`` (:class:`~depthguard.runtime.free_space_map.FreeSpaceSnapshot`)
        as ``sensor_msgs/PointCloud2`` on ``<ns>/obstacles`` (module docstring), stamped with its
        newest capture stamp; a map without a stamp (no frame yet), or after :meth:`close`, is not sent."""
        from depthguard.runtime.map_cloud import obstacle_cloud

        if not (math.isfinite(snapshot.stamp) and snapshot.stamp >= 0):
            return
        msg = obstacle_cloud(snapshot, snapshot.stamp, self._msgs.frame_id)
        with self._map_lock:
            if self._pubs is None:
                return
            if self._map_pub is None:
                self._map_pub = self.node.publisher(self.map_topic, OBSTACLES_TYPE, depth=1)
            self._map_pub.publish(msg)
            self.maps_published += 1

    def close(self) -> None:
        if self.path_checks is not None:
            self.path_checks.close()
            self.path_checks = None
        with self._map_lock:
            if self._pubs is None:
                return
            for p in [*self._pubs.values(), *([self._map_pub] if self._map_pub is not None else [])]:
                p.close()
            self._pubs = self._map_pub = None
        self.node.release()


def open_ros2_sink(context: dict, robot, watch_points=(), namespace: str = DEFAULT_NAMESPACE,
                   scaling_topic: str | None = DEFAULT_SCALING_TOPIC) -> Ros2Sink:
    """The sink on the run's node (shared with ``ros2:`` sources through ``context``)."""
    from depthguard.transport.ros2_zenoh import node_for

    return Ros2Sink(node_for(context), robot, watch_points, namespace, scaling_topic=scaling_topic)


def open_ros2(argument: str, rig, context: dict) -> Ros2Sink:
    """``ros2:[NAMESPACE]`` (:mod:`depthguard.runtime.sink_specs`): default ``/depthguard``; the
    node is the run's (``context``: ``ros2_domain``, ``ros2_router``, shared with ``ros2:`` sources)."""
    ns = argument or DEFAULT_NAMESPACE
    scaling = context.get("ros2_scaling_topic", DEFAULT_SCALING_TOPIC)
    scaling = None if scaling is None or scaling.lower() == "none" else scaling
    sink = open_ros2_sink(context, rig.robot, [(w.name, w.position) for w in rig.monitor.watch_points], ns, scaling)
    sink.describe = (f"publishing {ns.rstrip('/')}/override, reaction, markers (and obstacles with the map on) as ROS 2 topics "
                     f"(rmw_zenoh), answering {ns.rstrip('/')}/check_path/request"
                     + ("" if scaling is None else f", the speed scaling on {scaling}"))
    return sink
