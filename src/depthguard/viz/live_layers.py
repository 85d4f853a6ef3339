"""The layers and the panel of the live view (:class:`depthguard.viz.live.LiveView`), built once (R29).

:func:`build_scene` adds the cell, the robot's links (moved later by their poses),
the cameras' frustums and labels, the empty point clouds and the vector lines;
:func:`ensure_spheres` the control and watch points' spheres; :func:`build_gui`
the panel (text, rho slider, freeze, one switch per layer). Each fills the
view's ``layers`` (name -> scene handles) and its handles.
"""

from __future__ import annotations

import math

import numpy as np

from depthguard.viz import live_scene as scene

__all__ = ["build_scene", "ensure_spheres", "build_gui", "LAYERS", "LAYERS_OFF"]

#: the layers the panel can switch on and off
LAYERS = ("cell", "robot", "cameras", "points", "known-scene points", "obstacles", "free-space map",
          "control points", "vectors")
#: layers off until switched on
LAYERS_OFF = ("known-scene points",)


def wxyz(R: np.ndarray) -> np.ndarray:
    """(4,) unit quaternion (w, x, y, z) of the rotation matrix ``R`` (3, 3), viser's convention."""
    from viser import transforms as vtf

    return vtf.SO3.from_matrix(np.asarray(R, dtype=np.float64)).wxyz


def build_scene(view) -> None:
    """Lights, cell, robot links, frustums and labels, empty clouds and vectors (module docstring)."""
    sc = view.server.scene
    sc.configure_environment_map(hdri=None)
    sc.add_light_ambient("/lights/ambient", intensity=1.2)
    sc.add_light_directional("/lights/sun", intensity=2.0, position=(2.0, -3.0, 5.0), cast_shadow=False)
    view.layers = {name: [] for name in LAYERS}
    for i, obj in enumerate(view.rig.objects):
        m = obj.mesh
        h = sc.add_mesh_simple(f"/cell/{i}_{obj.name}", m.vertices.astype(np.float32),
                               m.faces.astype(np.uint32), color=(200, 200, 205), side="double",
                               opacity=0.5 if "wall" in obj.name else None)
        view.layers["cell"].append(h)
    view._links = []
    if view.robot is not None:
        local = view.robot.local_link_meshes()
        index = {n: k for k, n in enumerate(view.robot.link_names)}
        for name in view.robot.link_mesh_names:
            m = local[name]
            h = sc.add_mesh_simple(f"/robot/{name}", m.vertices.astype(np.float32), m.faces.astype(np.uint32),
                                   color=scene.ROBOT_COLOUR, side="double")
            view._links.append((index[name], h))
            view.layers["robot"].append(h)
        if view.rig.robot_q0 is not None:
            view._pose_robot(np.asarray(view.rig.robot_q0, dtype=float))
        view._data = view.robot.create_data()
    view._frustums = {}
    for cam in view.rig.cameras:
        fov = 2.0 * math.atan(cam.height / (2.0 * cam.fy))
        h = sc.add_camera_frustum(f"/cameras/{cam.id}", fov=fov, aspect=cam.width / cam.height, scale=0.2,
                                  color=scene.state_colour("waiting"), wxyz=wxyz(cam.world_from_camera[:3, :3]),
                                  position=cam.world_from_camera[:3, 3], thickness=0.01)
        lab = sc.add_label(f"/camera_labels/{cam.id}", cam.id, position=cam.world_from_camera[:3, 3])
        view._frustums[cam.id] = h
        view.layers["cameras"] += [h, lab]
    empty = np.zeros((0, 3), dtype=np.float32)
    view._clouds = {}
    for cam in view.rig.cameras:
        h = sc.add_point_cloud(f"/points/{cam.id}", empty, colors=np.zeros((0, 3), np.uint8), point_size=0.012)
        k = sc.add_point_cloud(f"/known/{cam.id}", empty, colors=scene.LABEL_COLOURS[scene.KNOWN],
                               point_size=0.008, visible=False)
        view._clouds[cam.id] = (h, k)
        view.layers["points"].append(h)
        view.layers["known-scene points"].append(k)
    view._near = sc.add_point_cloud("/obstacles", empty, colors=scene.NEAR_COLOUR, point_size=0.03)
    view.layers["obstacles"].append(view._near)
    # R37: the free-space map's occupied and unknown voxels (LiveView.write_map), a point per voxel centre
    view._map_cloud = sc.add_point_cloud("/free_space_map", empty, colors=np.zeros((0, 3), np.uint8),
                                         point_size=0.03, precision="float32")   # float16: 0.4 mm off at 1 m
    view.layers["free-space map"].append(view._map_cloud)
    view._spheres = []
    view._vectors = sc.add_line_segments("/vectors", np.zeros((1, 2, 3), np.float32),
                                         np.zeros((1, 2, 3), np.uint8), thickness=3.0,
                                         thickness_units="screen", visible=False)
    view.layers["vectors"].append(view._vectors)
    view._vectors_on = True


def ensure_spheres(view, names, is_watch) -> None:
    """One sphere per control / watch point of ``names`` (made again when the points change)."""
    if len(view._spheres) == len(names):
        return
    for h in view._spheres:
        h.remove()
    radii = {c.name: c.radius for c in view.robot.control_points} if view.robot is not None else {}
    view._spheres = []
    for n, w in zip(names, is_watch):
        # a translucent shell just outside the link (the sphere of the control point's radius lies inside it)
        r = 0.03 if w else float(radii.get(n, 0.05)) + 0.015
        h = view.server.scene.add_icosphere(f"/points_of_robot/{n}", radius=r, color=scene.CLEAR_COLOUR,
                                            opacity=0.55, subdivisions=2,
                                            visible=view.gui_layers["control points"].value)
        view._spheres.append(h)
    view.layers["control points"] = list(view._spheres)


def build_gui(view) -> None:
    """The panel: text, rho slider (``Monitor.set_rho``), freeze, one switch per layer."""
    gui = view.server.gui
    view.gui_panel = gui.add_markdown("waiting for the monitor ...")
    view.gui_rho = gui.add_slider("rho (m)", min=0.1, max=1.5, step=0.01, initial_value=round(view.rho, 2),
                                  hint="radius of surveillance: Monitor.set_rho")

    @view.gui_rho.on_update
    def _(_event) -> None:
        value = float(view.gui_rho.value)
        if view._quiet_rho:
            return
        if view._monitor is not None:
            try:
                view._monitor.set_rho(value)
            except ValueError as exc:
                view.errors.append(str(exc))
                return
        view.rho = value

    view.gui_freeze = gui.add_checkbox("freeze", False, hint="stop updating the scene (the monitor runs on)")
    view.gui_layers = {}
    with gui.add_folder("layers"):
        for name in LAYERS:
            box = gui.add_checkbox(name, name not in LAYERS_OFF)
            view.gui_layers[name] = box
            box.on_update(lambda _e, name=name: view.set_layer(name, view.gui_layers[name].value))
