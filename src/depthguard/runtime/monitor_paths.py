"""The monitor's free-space map and path checks (R21, R22, R37): a mixin of
:class:`~depthguard.runtime.monitor.Monitor` (its ``rig``, ``config``, ``robot``, ``joints``,
``sinks``, ``_workers``, ``_camera_ids``, ``_policies`` and ``free_space``).
"""

from __future__ import annotations

__all__ = ["MonitorPaths"]


class MonitorPaths:
    """:meth:`start_free_space`, :meth:`watch_path`, :meth:`check_path` of the monitor."""

    def start_free_space(self, hz: float | None = None, voxel_size: float | None = None, on_snapshot=None,
                         threaded: bool = True):
        """Start the free-space map's thread (:mod:`depthguard.runtime.free_space_map`) at ``hz``
        (default ``config.free_space_hz``) with voxels of ``voxel_size`` m (default
        ``config.free_space_voxel``); returns its :class:`FreeSpaceWorker`. ``threaded=False``:
        no thread, the caller builds each map with ``free_space.update_now()`` (a simulation in
        simulated time)."""
        from depthguard.runtime.free_space_map import FreeSpaceWorker, RuntimeFreeSpace

        if self.free_space is not None:
            return self.free_space
        cfg = self.config
        space = RuntimeFreeSpace(self.rig, self._camera_ids, voxel_size or cfg.free_space_voxel,
                                 cfg.robot_offset, cfg.robot_padding,
                                 scene_padding=cfg.free_space_scene_padding)
        self.free_space = FreeSpaceWorker(space, self._workers, self._latest_q, hz or cfg.free_space_hz,
                                          lambda snap: self._on_snapshot(snap, on_snapshot), threaded=threaded)
        return self.free_space

    def _path_policy(self):
        return next((p for n, p in self._policies if n == "path_watch"), None)

    def _on_snapshot(self, snap, user=None) -> None:
        """After each map swap (the map's thread): the watched path's fresh verdict (R37), then ``user``."""
        from depthguard.runtime.free_space_map import check_path_in

        pol = self._path_policy()
        path = None if pol is None else pol.path
        if path is not None:
            pol.set_verdict(check_path_in(snap, self.robot, path.stamps, path.q, self.config.robot_padding), path)
        for sink in self.sinks:                  # the map out (R37): sinks that take it, e.g. mcap:
            write_map = getattr(sink, "write_map", None)
            if write_map is not None:
                write_map(snap)
        if user is not None:
            user(snap)

    def watch_path(self, stamps, q) -> None:
        """R37: watch the path the robot runs — ``stamps`` (n,) s, ``q`` (n, dof) rad; ``None``
        stops watching. Needs ``path_watch`` among ``config.reactions``; starts the map if it is
        off. A bad path raises ``ValueError`` naming the waypoint."""
        from depthguard.control.path_check import validate_path
        from depthguard.runtime.free_space_map import check_path_in

        pol = self._path_policy()
        if pol is None:
            raise ValueError("the path watch is not among the monitor's reactions "
                             "(monitor: reactions: [repulsion, path_watch])")
        if stamps is None:
            pol.clear_path()
            return
        t, Q = validate_path(stamps, q, self.robot)
        path = pol.set_path(t, Q)
        snap = self.start_free_space().snapshot
        if snap is not None:
            pol.set_verdict(check_path_in(snap, self.robot, t, Q, self.config.robot_padding), path)

    def check_path(self, stamps, q, padding: float | None = None, fresh: bool = False):
        """R22, R37: a planned path — ``stamps`` (n,) s increasing, ``q`` (n, dof) rad — against the
        newest free-space map: a :class:`~depthguard.control.path_check.PathVerdict` (per segment
        safe / maybe / unsafe, the first segment not safe, the reasons). ``padding`` m on the
        robot's capsules (default ``config.robot_padding``); ``fresh`` builds a map from the newest
        frames first. Starts the map if it is off; no map yet (no frame): every segment ``maybe``.
        A bad path raises ``ValueError`` naming the waypoint."""
        from depthguard.control.path_check import PathVerdict, SegmentVerdict, validate_path
        from depthguard.runtime.free_space_map import check_path_in

        worker = self.start_free_space()
        snap = worker.update_now() if fresh or worker.snapshot is None else worker.snapshot
        pad = self.config.robot_padding if padding is None else float(padding)
        if snap is None:
            t, _ = validate_path(stamps, q, self.robot)
            return PathVerdict(tuple(SegmentVerdict(i, float(t[i]), float(t[i + 1]), "maybe", why="no map yet (no frame)")
                                     for i in range(len(t) - 1)))
        return check_path_in(snap, self.robot, stamps, q, pad)

    def _latest_q(self):
        latest = self.joints.latest()
        return None if latest is None else latest[1]
