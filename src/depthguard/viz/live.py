"""``LiveView``: what the monitor sees, live in the browser (viser) — a monitor sink (R29, R31).

    view = LiveView(rig, host="127.0.0.1", port=8080)      # starts the web server and its thread
    monitor.sinks.append(view); view.attach(monitor)        # or Monitor(rig, sinks=[view])
    ... open http://127.0.0.1:8080 ...
    view.close()                                            # (monitor.close() closes it too)

The control thread pays for one lock and one assignment per cycle: the sink
call keeps a reference to the newest :class:`~depthguard.runtime.result.Reaction`
(its arrays are already its own copies). The view's own thread
(``depthguard-view``, lower priority like the monitor's workers) wakes at
``rate_hz`` (default 15 Hz), takes the newest reaction, reads each camera's
newest processed frame from the monitor's camera workers (their ``product``,
under the worker's lock, which the control thread never takes), and updates
the scene:

- the cell's static meshes (grey), the robot at the reaction's joints (orange);
- each camera's frustum coloured by its state (fresh green, stale yellow,
  waiting grey, anything else red = untrusted);
- each camera's newest frame, every ``stride``-th pixel, as points: removed
  as the robot (violet), as the known scene (grey), the rest (blue), and the
  rest within rho of a control point (red) — the view's own per-pixel
  reading of the frame, for looking; the monitor's distances come from its
  depth grid;
- control and watch points as translucent spheres coloured by distance (red
  near, green far or nothing within rho), magenta where no camera can judge
  (R26), with a line to the nearest obstacle (which may be space hidden
  behind what a camera sees: unknown space is an obstacle);
- the free-space map (R37; a run with the map on, :meth:`LiveView.write_map` from the map's
  thread): a point per occupied (brown) or unknown (pale grey-blue) voxel centre, the robot's
  body left out — the points of ``/depthguard/obstacles`` — redrawn at each map update;
- a panel: override and reasons, per camera state / frame rate / age, the
  step time; a rho slider (``Monitor.set_rho``) and one switch per layer.

The server binds ``127.0.0.1`` unless told otherwise (it has no
authentication: anyone who reaches the port can change rho). A replay
(``depthguard view DIR|BAG``, :mod:`depthguard.viz.replay`) calls :meth:`show`
with a snapshot instead, its frames in ``snapshot.extra["frames"]``.
"""

from __future__ import annotations

import contextlib
import logging
import math
import sys
import threading
import time
from collections import deque

import numpy as np

from depthguard.runtime.realtime import background_priority
from depthguard.viz import live_scene as scene
from depthguard.viz.live_layers import LAYERS, build_gui, build_scene, ensure_spheres, wxyz as _wxyz

__all__ = ["LiveView", "LAYERS"]

#: where a browser's camera starts: eye and target (world m), vertical field of view (rad)
VIEW_EYE, VIEW_TARGET, VIEW_FOV = (2.3, -0.9, 1.4), (-0.3, 0.1, 0.25), math.radians(50.0)


class _ClosedBeforeRequest(logging.Filter):
    """Drops websockets' "opening handshake failed" (a traceback on the command's output) when
    the peer closed before it sent a request — a browser's speculative connection, or a tab
    closed while connecting: nothing went wrong with the view. Other failures still show."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.getMessage() != "opening handshake failed" or not record.exc_info:
            return True
        exc, seen = record.exc_info[1], 0
        while exc is not None and seen < 10:
            if isinstance(exc, EOFError):
                return False
            exc, seen = exc.__cause__ or exc.__context__, seen + 1
        return True


def _quiet_handshakes() -> None:
    logger = logging.getLogger("websockets.server")
    if not any(isinstance(f, _ClosedBeforeRequest) for f in logger.filters):
        logger.addFilter(_ClosedBeforeRequest())


class LiveView:
    """The live view of one cell (module docstring).

    rig : the :class:`~depthguard.rig.Rig` (cameras, static meshes, robot).
    host, port : where the web server listens (port 0: any free port; a busy port: the next free one —
        :attr:`url` says which).
    rate_hz : scene updates per second (>= 10 by default 15).
    stride : every ``stride``-th pixel of each frame is drawn (8: 80 x 60 points of a 640 x 480 frame).
    monitor : a :class:`~depthguard.runtime.Monitor` to read frames from and set rho on (or :meth:`attach`).
    """

    direct = True                    # keeps the newest reaction; drawn on its own thread (sink_specs)

    def __init__(self, rig, *, host: str = "127.0.0.1", port: int = 8080, rate_hz: float = 15.0,
                 stride: int = 8, monitor=None, title: str | None = None, start: bool = True):
        import viser

        if not rate_hz > 0:
            raise ValueError(f"view rate must be > 0 Hz (got {rate_hz})")
        if int(stride) < 1:
            raise ValueError(f"view stride must be >= 1 pixel (got {stride})")
        if not 0 <= int(port) <= 65535:
            raise ValueError(f"view port must be 0..65535 (got {port})")
        self.rig = rig
        self.robot = rig.robot
        self.period = 1.0 / float(rate_hz)
        self.stride = int(stride)
        self.rho = float(rig.monitor.rho)
        self.robot_offset = float(rig.monitor.robot_offset)
        self._lock = threading.Lock()
        self._latest = None              # the newest Reaction (live) or Snapshot (playback)
        self._shown = None
        self.received = 0                # reactions given to the sink
        self.updates = 0                 # scene updates sent
        self.update_s: deque = deque(maxlen=2000)     # s per update that drew something new
        self.errors: list[str] = []
        self.cpu_s = 0.0                 # CPU seconds of the view's thread
        self._monitor = None
        self._versions: dict[str, int] = {}
        self._frames_seen: dict[str, tuple[float, int]] = {}
        self._rates: dict[str, float] = {}
        self._static: dict[str, np.ndarray] = {}
        self._near_points: dict[str, np.ndarray] = {}     # camera id -> its points near the robot (N, 3)
        self._map_latest = None          # the newest free-space map (write_map), and the one drawn
        self._map_shown = None
        self.maps_drawn = 0
        self._panel_at = -math.inf
        self._panel_due = None           # a snapshot whose panel text the rate limit held back
        self._cps = None
        self._q_shown = None
        self._quiet_rho = False
        self.note = ""
        _quiet_handshakes()
        with contextlib.redirect_stdout(sys.stderr):     # viser's banner: not on the command's output
            self.server = viser.ViserServer(host=host, port=int(port), label=title or f"depthguard - {rig.name}",
                                            verbose=False)
        # viser's event-loop thread (it encodes and sends the scene): the workers' lower priority
        web_thread = getattr(getattr(self.server, "_websock_server", None), "_server_thread", None)
        background_priority(getattr(web_thread, "native_id", None))
        # no share button: it would open a tunnel through viser's public relay (nothing leaves the machine)
        self.server.gui.configure_theme(show_share_button=False, control_width="medium")
        self.server.scene.set_up_direction("+z")
        self.server.initial_camera.position = VIEW_EYE
        self.server.initial_camera.look_at = VIEW_TARGET
        self.server.initial_camera.fov = VIEW_FOV
        self._build_scene()
        self._build_gui()
        if monitor is not None:
            self.attach(monitor)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="depthguard-view", daemon=True)
        if start:
            self._thread.start()

    # ------------------------------------------------------------ the sink (control thread)
    def __call__(self, reaction) -> None:
        """Keep the newest reaction: one lock, one assignment (module docstring)."""
        with self._lock:
            self._latest = reaction
            self.received += 1

    def write_map(self, snapshot) -> None:
        """R37: keep the newest free-space map (the map's thread: one lock, one assignment); the
        view's thread draws it as the ``free-space map`` layer (:func:`~depthguard.viz.live_scene.map_points`)."""
        with self._lock:
            self._map_latest = snapshot

    def show(self, snapshot: scene.Snapshot) -> None:
        """Show ``snapshot`` at the next update (playback)."""
        with self._lock:
            self._latest = snapshot

    def attach(self, monitor) -> None:
        """Read frames from ``monitor``'s camera workers and set its rho from the panel."""
        self._monitor = monitor
        self.rho = float(monitor.config.rho)
        self._quiet_rho = True                 # showing the monitor's rho must not set it (rounded)
        try:
            self.gui_rho.value = round(self.rho, 2)
        finally:
            self._quiet_rho = False

    def freeze(self, on: bool = True) -> None:
        """Stop (or resume) updating the scene; the monitor and the sink go on."""
        self.gui_freeze.value = bool(on)

    @property
    def shown_q(self) -> np.ndarray | None:
        """(dof,) rad: the joints the robot is drawn at (None before the first reaction with joints)."""
        return None if self._q_shown is None else self._q_shown.copy()

    @property
    def url(self) -> str:
        return f"http://{self.server.get_host()}:{self.server.get_port()}/"

    @property
    def port(self) -> int:
        return int(self.server.get_port())

    # ------------------------------------------------------------ set-up
    def _build_scene(self) -> None:
        build_scene(self)

    def _ensure_spheres(self, names, is_watch) -> None:
        ensure_spheres(self, names, is_watch)

    def _build_gui(self) -> None:
        build_gui(self)

    def set_layer(self, name: str, on: bool) -> None:
        """Show or hide one of :data:`LAYERS`."""
        if name not in self.layers:
            raise ValueError(f"no layer {name!r}; layers: {', '.join(LAYERS)}")
        if self.gui_layers[name].value != bool(on):
            self.gui_layers[name].value = bool(on)
        if name == "vectors":
            self._vectors_on = bool(on)
        for h in self.layers[name]:
            h.visible = bool(on)

    # ------------------------------------------------------------ the view's thread
    def _run(self) -> None:
        from depthguard.runtime.ingest import background_thread

        try:
            background_thread()
        except Exception:  # noqa: BLE001 - numba missing or no priority change: the view still runs
            pass
        next_t = time.perf_counter()
        while not self._stop.is_set():
            next_t += self.period
            t0, c0 = time.perf_counter(), time.thread_time()
            try:
                if self.update():
                    self.update_s.append(time.perf_counter() - t0)
            except Exception as exc:  # noqa: BLE001 - the view must never stop the monitor
                msg = f"{type(exc).__name__}: {exc}"
                if not self.errors or self.errors[-1] != msg:
                    self.errors.append(msg)
                    from depthguard.progress import log
                    log(f"view: {msg}")
            self.cpu_s += time.thread_time() - c0
            wait = next_t - time.perf_counter()
            if wait < 0:
                next_t = time.perf_counter()
            else:
                self._stop.wait(wait)

    def update(self) -> bool:
        """One scene update from the newest reaction or snapshot; False when nothing new."""
        if self.gui_freeze.value:
            return False
        with self._lock:
            latest, fs_map = self._latest, self._map_latest
        drew_map = self._update_map(fs_map)
        if latest is None or latest is self._shown:
            self._update_points(self._cps)
            if self._panel_due is not None and time.perf_counter() - self._panel_at > 0.25:
                self._write_panel(self._panel_due)     # the last snapshot's text, held back by the rate limit
            return drew_map
        self._shown = latest
        snap = latest if isinstance(latest, scene.Snapshot) else scene.snapshot_of_reaction(latest)
        with self.server.atomic():
            self._cps = cps = self._update_robot(snap)
            self._update_points(cps, snap)
            for cid, st in snap.cameras.items():
                h = self._frustums.get(cid)
                if h is not None:
                    col = scene.state_colour(st["state"])
                    if tuple(h.color) != col:
                        h.color = col
        if time.perf_counter() - self._panel_at > 0.25:
            self._write_panel(snap)
        else:
            self._panel_due = snap
        self.updates += 1
        return True

    def _update_map(self, fs_map) -> bool:
        """Draw the free-space map ``fs_map`` if it is new (True when drawn)."""
        if fs_map is None or fs_map is self._map_shown:
            return False
        self._map_shown = fs_map
        pts, colours = scene.map_points(fs_map)
        h = self._map_cloud
        with self.server.atomic():
            h.points, h.colors = pts, colours
            h.point_size = float(fs_map.grid.voxel_size) * 0.6
        self.maps_drawn += 1
        return True

    def _write_panel(self, snap: scene.Snapshot) -> None:
        """The panel's text for ``snap`` (at most 4 times a second)."""
        now = time.perf_counter()
        self._panel_at = now
        self._panel_due = None
        self.gui_panel.content = scene.panel_markdown(snap, self._camera_rates(now), self._step_ms(snap),
                                                      self.rho, self.note)

    def _pose_robot(self, q: np.ndarray) -> None:
        poses = self.robot.link_poses(q)
        for k, h in self._links:
            h.wxyz = _wxyz(poses[k][:3, :3])
            h.position = poses[k][:3, 3]

    def _update_robot(self, snap: scene.Snapshot):
        """Robot pose, control/watch spheres and vectors; returns the control points (M, 3) or None."""
        if self.robot is None:
            return None
        self._ensure_spheres(snap.names, snap.is_watch)
        if snap.q is None:
            return None
        q = np.asarray(snap.q, dtype=float)
        if self._q_shown is None or not np.array_equal(q, self._q_shown):
            self._pose_robot(q)
            self._q_shown = q
        self.robot.forward(q, self._data)
        cps = np.array(self._data.cp_positions, dtype=float)
        cfg = self._monitor.config if self._monitor is not None else self.rig.monitor
        watch = [w.position for w in cfg.watch_points]
        pos = np.concatenate([cps, np.asarray(watch, dtype=float).reshape(-1, 3)])
        if len(pos) != len(snap.names):
            return cps
        cols = scene.distance_colours(snap.distance, snap.observed, self.rho)
        for h, p, c in zip(self._spheres, pos, cols):
            h.position = p
            if tuple(h.color) != tuple(int(x) for x in c):
                h.color = tuple(int(x) for x in c)
        seen = np.isfinite(snap.distance) & snap.observed
        if seen.any() and self._vectors_on:
            a = pos[seen]
            b = a + snap.direction[seen] * snap.distance[seen][:, None]
            self._vectors.points = np.stack([a, b], axis=1).astype(np.float32)
            self._vectors.colors = np.repeat(cols[seen][:, None, :], 2, axis=1)
            self._vectors.visible = True
        else:
            self._vectors.visible = False
        return cps

    def _update_points(self, cps, snap: scene.Snapshot | None = None) -> None:
        """Each camera's newest processed frame, when it changed: from the monitor's camera
        workers (live), or from ``snap.extra["frames"]`` (a replay: camera id ->
        :class:`~depthguard.runtime.ingest.CameraProduct` or None, ``depthguard.viz.replay``)."""
        mon = self._monitor
        if mon is not None:
            products = {}
            for cid, w in list(mon.fusion.workers.items()):
                with w.lock:
                    products[cid] = (w.camera, w.product)
        elif snap is not None and snap.extra.get("frames") is not None:
            cams = {c.id: c for c in self.rig.cameras}
            products = {cid: (cams[cid], p) for cid, p in snap.extra["frames"].items() if cid in cams}
        else:
            return
        self._draw_frames(products, cps)

    def _draw_frames(self, products: dict, cps) -> None:
        """Draw ``products`` (camera id -> (camera, CameraProduct or None)) whose version changed;
        None clears the camera's points (a replay before its first frame)."""
        changed = False
        for cid, (cam, p) in products.items():
            version = None if p is None else p.version
            if self._versions.get(cid) == version:
                continue
            self._versions[cid] = version
            changed = True
            handles = self._clouds.get(cid)
            if p is None:
                if handles is not None:
                    handles[0].points = np.zeros((0, 3), np.float32)
                    handles[0].colors = np.zeros((0, 3), np.uint8)
                    handles[1].points = np.zeros((0, 3), np.float32)
                self._near_points.pop(cid, None)
                continue
            if cid not in self._static:
                from depthguard.filtering.expected import ExpectedDepth
                self._static[cid] = ExpectedDepth(cam, None, self.rig.static_meshes()).static
            pts, plab = scene.frame_points(cam, p.depth, p.robot_depth, self._static[cid], self.robot_offset,
                                           self.stride)
            near = scene.near_mask(pts, cps if cps is not None else np.zeros((0, 3)), self.rho) & \
                (plab == scene.OTHER)
            if handles is not None:
                known = plab == scene.KNOWN
                handles[0].points = pts[~known]
                handles[0].colors = scene.point_colours(plab[~known], near[~known])
                if handles[1].visible:
                    handles[1].points = pts[known]
            self._near_points[cid] = pts[near]
        if changed:
            near_all = list(self._near_points.values())
            pts = np.concatenate(near_all) if near_all else np.zeros((0, 3), np.float32)
            self._near.points = pts.astype(np.float32)

    def _camera_rates(self, now: float) -> dict:
        mon = self._monitor
        if mon is None:
            return {}
        for cid, w in list(mon.fusion.workers.items()):
            frames = w.frames
            t_prev, f_prev = self._frames_seen.get(cid, (None, None))
            if t_prev is None:
                self._frames_seen[cid] = (now, frames)
            elif now - t_prev >= 1.0:
                self._rates[cid] = (frames - f_prev) / (now - t_prev)
                self._frames_seen[cid] = (now, frames)
        return dict(self._rates)

    def _step_ms(self, snap: scene.Snapshot) -> dict:
        mon = self._monitor
        if mon is not None:
            recent = np.asarray(mon.step_s[-2500:], dtype=float)
            if len(recent):
                return {"p50": float(np.percentile(recent, 50) * 1e3), "p99": float(np.percentile(recent, 99) * 1e3)}
        return {} if not math.isfinite(snap.step_s) else {"last": snap.step_s * 1e3}

    # ------------------------------------------------------------ end
    def close(self) -> None:
        """Stop the view's thread and the web server."""
        if self._stop.is_set():
            return
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(2.0)
        with contextlib.redirect_stdout(sys.stderr):
            self.server.stop()

    def __enter__(self) -> "LiveView":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_view(argument: str, rig, context: dict) -> LiveView:
    """``view:[[HOST:]PORT]`` (:mod:`depthguard.runtime.sink_specs`): default 127.0.0.1:8080 (a busy
    port: the next free); anyone who reaches it can change rho. Direct: it keeps the newest reaction."""
    from depthguard.viz.sinks import view_address

    host, port = view_address(argument)
    view = LiveView(rig, host=host, port=port)
    view.describe = f"live view at {view.url}"
    return view
