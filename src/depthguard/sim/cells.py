"""The built-in cells: a rig file (``data/cells/<name>.yaml``) plus a scene script each.

``load_cell(name) -> Cell``; ``list_cells()`` gives the names. A
:class:`Cell` holds the :class:`~depthguard.rig.Rig`, the :class:`Scene`
(static CAD from the rig, the robot on a scripted joint path, people and
props) and named *situations*: times of the scene worth looking at
(``cell.situations[name].time``; ``cell.scene_for(name) -> (scene, t)``).
``cell_from_rig(rig) -> Cell`` makes one of any rig (a user's rig file): the
rig's static objects and its robot at the rig's joints, nobody else.

- ``flacco-walls`` (Flacco 2014 §4): table plane and a vertical wall, one Kinect.
- ``flacco-cell`` (Flacco 2014 §5, 2015 §VIII): LWR IV, two Kinects in a 7 x 7 m
  lab room (floor, 3 m walls); a person walks in, reaches for the end effector,
  carries a box; situations
  ``robot_alone``, ``reach``, ``carry``, ``shadow`` (2015 fig. 8) and
  ``hidden_hand`` (2015 fig. 9).
- ``ur3-cell`` (Oščádal 2022): UR3 workstation, four RealSense D435, in a 7 x 7 m
  room (floor at z = 0, 3 m walls); an arm reaches in and a box is put down.
- ``fr3-cell``: a Franka FR3 (franky-sim's model, :func:`depthguard.robot.builtin.fr3_urdf_path`)
  on a workbench, two RealSense D435 on tripods; it swings its first joint along the joint
  path of ``data/cells/fr3-cell.path.csv`` (the path ``--sink franky:HOST,path=fr3-cell``
  runs) and a person walks in towards that path, stands at its edge and leaves. Needs
  franky-sim installed, so it is not among :func:`list_cells` (the demo, the benchmarks and
  the calibration study run every listed cell): load it by name (:data:`EXTRA_CELLS`).
- ``c-arm-room`` (Hamersma 2011): intervention room, ceiling C-arm
  (:mod:`depthguard.sim.carm`) as the machine, patient, doctor, two nurses,
  21 ToF cameras; situations ``setup1`` … ``setup6``.

The two robot cells have a floor and walls, as real cells do: every camera ray
returns (the far walls may lie beyond a sensor's rated range, within the range
it returns, :mod:`depthguard.sensors`), so "no return" means something
dark or a dropout, never "the ray left the scene" (R28, R32).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Callable

import numpy as np

from depthguard.geometry.primitives import Box, Capsule, Primitive, Sphere
from depthguard.sim.carm import CArm, CArmPose
from depthguard.sim.people import BodyShape, Carry, Key, Person
from depthguard.sim.scene import JointPath, Prop, Scene
from depthguard.transforms import pose

__all__ = ["Cell", "Situation", "load_cell", "list_cells", "cell_from_rig", "cell_rig_path", "cell_path_file",
           "CELL_NAMES", "EXTRA_CELLS"]

CELL_NAMES = ("flacco-walls", "flacco-cell", "ur3-cell", "c-arm-room")
#: cells loadable by name that need an optional package (fr3-cell: franky-sim's FR3 model)
EXTRA_CELLS = ("fr3-cell",)


@dataclass(frozen=True)
class Situation:
    """A named moment of a cell's scene: scene time ``time`` (s) and what it shows.

    ``float(situation)`` is its time, so ``scene.meshes_at(float(cell.situations["shadow"]))`` works.
    """
    name: str
    time: float
    description: str = ""

    def __float__(self) -> float:
        return float(self.time)


@dataclass
class Cell:
    """A built-in cell: rig, scene, description and named situations."""
    name: str
    rig: object
    scene: Scene
    description: str
    situations: dict[str, Situation] = field(default_factory=dict)

    def scene_for(self, situation: str) -> tuple[Scene, float]:
        """``(scene, t)`` of a named situation; ``ValueError`` listing the known ones."""
        try:
            s = self.situations[situation]
        except KeyError:
            known = ", ".join(self.situations) or "none"
            raise ValueError(f"cell {self.name!r} has no situation {situation!r}; situations: {known}") from None
        return self.scene, s.time

    def time_of(self, situation: str) -> float:
        return self.scene_for(situation)[1]

    @property
    def robot(self):
        """The machine of the cell: the rig's robot, or the scene's (the C-arm)."""
        return self.scene.robot


def cell_rig_path(name: str) -> Path:
    """Path of the shipped rig file of a built-in cell."""
    _check_name(name)
    return Path(str(resources.files("depthguard") / "data" / "cells" / f"{name}.yaml"))


def cell_path_file(name: str) -> Path:
    """The shipped joint path of a cell's robot (``data/cells/<name>.path.csv``: 1 waypoint a line, rad)
    for a robot sink that runs a path (``--sink franky:HOST,path=<name>``); ``FileNotFoundError``
    when the cell has none."""
    p = Path(str(resources.files("depthguard") / "data" / "cells" / f"{name}.path.csv"))
    if name not in CELL_NAMES + EXTRA_CELLS or not p.is_file():
        raise FileNotFoundError(f"cell {name!r} has no shipped joint path")
    return p


def ring_fixture_mesh():
    """The ``ur3-cell``'s STL fixture as made: a trimesh annulus (ring part holder) in millimetres,
    inner radius 30, outer 60, height 40, standing on z = 0 (``data/cells/meshes/ring_fixture.stl``)."""
    import trimesh

    m = trimesh.creation.annulus(r_min=30.0, r_max=60.0, height=40.0, sections=48)
    m.apply_translation([0.0, 0.0, 20.0])
    return m


def write_fixture_meshes(directory: str | Path) -> list[Path]:
    """Write the cells' mesh files (the shipped ones were made by this) into ``directory``."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    p = d / "ring_fixture.stl"
    ring_fixture_mesh().export(p)
    return [p]


def list_cells() -> list[str]:
    """Names of the built-in cells."""
    return list(CELL_NAMES)


def load_cell(name: str) -> Cell:
    """The built-in cell ``name`` (one of :func:`list_cells`)."""
    from depthguard.rig import Rig

    _check_name(name)
    rig = Rig.load(cell_rig_path(name))
    scene, situations, description = _BUILDERS[name](rig)
    scene.name = name
    return Cell(name, rig, scene, description, {s.name: s for s in situations})


def cell_from_rig(rig, name: str | None = None) -> Cell:
    """A :class:`Cell` for any rig (a user's rig file, R2): its static scene is the rig's
    objects, the robot (if any) stands still at the rig's joints (``rig.robot_q0``, rad), and
    there are no people, props or situations. ``name`` defaults to the rig's name."""
    from depthguard.rig import Rig

    if not isinstance(rig, Rig):
        raise TypeError(f"cell_from_rig needs a depthguard.rig.Rig, got {type(rig).__name__}")
    label = name or rig.name
    scene = Scene(rig.objects, robot=rig.robot, robot_q0=rig.robot_q0, duration=0.0, name=label)
    where = f" ({rig.path})" if rig.path is not None else ""
    description = rig.description or f"rig {rig.name}{where}: its static objects and robot at its rig joints"
    return Cell(label, rig, scene, description, {})


def _check_name(name: str) -> None:
    if name not in CELL_NAMES + EXTRA_CELLS:
        raise ValueError(f"unknown cell {name!r}; built-in cells: {', '.join(CELL_NAMES + EXTRA_CELLS)}")


# ====================================================================== cells
def _flacco_walls(rig):
    scene = Scene(rig.objects, duration=0.0)
    sits = [Situation("static", 0.0, "the table plane and the wall (nothing moves)")]
    return scene, sits, "Flacco 2014 §4: table plane z = 0.04 m and a vertical wall, one Kinect v1"


FLACCO_FLOOR = -0.85


def _flacco_cell(rig):
    robot = rig.robot
    home = np.asarray(rig.robot_q0, dtype=float)
    dq = np.zeros(robot.dof)
    dq[0], dq[1] = 0.5, 0.2
    path = JointPath([(0.0, home), (3.0, home + dq), (6.0, home), (10.0, home), (13.0, home - dq),
                      (16.0, home)])
    ee_home = robot.control_point_positions(home)[0]
    cp_names = [c.name for c in robot.control_points]

    # the box waiting on the side table (top at z = -0.1)
    box = Prop("box", Box(size=(0.3, 0.2, 0.2)), pose(t=[-1.1, 1.0, 0.0]))
    # a hand point hidden behind the robot's forearm as seen from the principal camera
    cam0 = rig.camera("cam0").position
    fa = robot.control_point_positions(home)[cp_names.index("forearm_2") if "forearm_2" in cp_names else 0]
    ray = (fa - cam0) / np.linalg.norm(fa - cam0)
    hidden = fa + 0.20 * ray
    shadow_xy = (0.8, -1.0)
    keys = [
        Key(2.0, (-2.6, -0.8), 0.0),
        Key(6.0, (-1.05, -0.2), 0.0),
        Key(7.0, (-1.05, -0.2), 0.0),
        Key(9.0, (-1.05, -0.2), 0.0, right=tuple(ee_home + [-0.07, -0.03, 0.0])),   # reaches for the EE
        Key(10.0, (-1.05, -0.2), 0.0, right=tuple(ee_home + [-0.07, -0.03, 0.0])),
        Key(11.5, (-1.1, 0.5), math.pi / 2),
        Key(13.0, (-1.1, 0.7), math.pi / 2),
        Key(14.0, (-1.1, 0.7), math.pi / 2, right=(-1.1, 1.0, 0.15)),              # grips the box
        Key(14.5, (-1.1, 0.7), math.pi / 2, right=(-1.1, 0.95, 0.3)),              # lifts it
        Key(15.2, (-1.1, 0.45), math.pi / 2, right=(-1.0, 0.75, 0.2)),             # steps back with it
        Key(16.5, (-1.2, -0.75), 0.0),                                                 # carries it round
        Key(19.0, (0.0, -0.75), math.pi / 2),
        Key(20.0, (0.0, -0.75), math.pi / 2, right=(0.2, -0.25, 0.25)),              # puts it down
        Key(21.5, (0.0, -1.2), math.pi / 2),
        Key(24.0, shadow_xy, math.atan2(-shadow_xy[1], -shadow_xy[0]), right=(0.45, -0.55, 0.5)),
        Key(26.0, shadow_xy, math.atan2(-shadow_xy[1], -shadow_xy[0]), right=(0.45, -0.55, 0.5)),
        Key(27.2, (0.9, 0.8), math.pi),                                             # walks round the robot
        Key(28.3, (-0.55, 0.75), math.pi),
        Key(28.9, (-0.7, 0.7), math.atan2(-0.7, 0.7)),
        Key(30.0, (-0.7, 0.7), math.atan2(-0.7, 0.7), right=tuple(hidden)),          # hand behind the robot
        Key(32.0, (-0.7, 0.7), math.atan2(-0.7, 0.7), right=tuple(hidden)),
    ]
    person = Person("operator", keys, floor_z=FLACCO_FLOOR, present=(2.0, math.inf),
                    carries=[Carry("box", "right", 14.0, 20.0, (0.0, -0.08, -0.15))])
    scene = Scene(rig.objects, robot=robot, robot_path=path, people=[person], props=[box], duration=32.0)
    sits = [
        Situation("robot_alone", 1.0, "the robot moving, nobody in the cell"),
        Situation("reach", 9.5, "the person's right hand 7 cm from the end effector"),
        Situation("carry", 17.5, "the person carries a box past the robot"),
        Situation("shadow", 25.0, "Flacco 2015 fig. 8: a person between the principal camera (cam0) "
                                  "and the robot, more than 0.5 m from it"),
        Situation("hidden_hand", 31.0, "Flacco 2015 fig. 9: a hand right behind the robot as seen from "
                                       "cam0, visible to cam1"),
    ]
    return scene, sits, ("Flacco 2014 §5 / 2015 §VIII: LWR IV, two Kinect v1 4 m apart in a 7 x 7 m lab room; "
                         "a person walks in, reaches for the end effector, carries a box")


def _ur3_cell(rig):
    robot = rig.robot
    q0 = np.asarray(rig.robot_q0, dtype=float)
    q1 = q0 + np.array([0.8, 0.3, -0.4, 0.0, 0.0, 0.0])
    q2 = q0 + np.array([-0.7, 0.2, -0.2, 0.0, 0.0, 0.0])
    path = JointPath([(0.0, q0), (4.0, q1), (8.0, q1), (12.0, q2), (16.0, q0)])
    box = Prop("box", Box(size=(0.15, 0.1, 0.08)), pose(t=[0.0, -3.0, 0.04]))  # on the floor, out of sight
    keys = [
        Key(1.0, (1.2, -1.7), math.pi * 0.75),
        Key(3.0, (0.0, -0.62), math.pi / 2),
        Key(4.0, (0.0, -0.62), math.pi / 2),
        Key(6.0, (0.0, -0.62), math.pi / 2, right=(0.2, -0.15, 1.0)),     # the arm reaches in
        Key(7.0, (0.0, -0.62), math.pi / 2, right=(0.2, -0.15, 1.0)),
        Key(8.5, (0.0, -0.62), math.pi / 2),
        Key(9.5, (0.0, -0.62), math.pi / 2, left=(-0.2, -0.3, 0.93)),     # puts the box down
        Key(10.0, (0.0, -0.62), math.pi / 2, left=(-0.2, -0.3, 0.93)),
        Key(11.0, (0.0, -1.2), math.pi / 2),
        Key(14.0, (1.5, -1.8), -math.pi / 4),
    ]
    person = Person("operator", keys, floor_z=0.0, present=(1.0, 15.0),
                    carries=[Carry("box", "left", 1.0, 10.0, (0.0, 0.0, -0.09))])
    scene = Scene(rig.objects, robot=robot, robot_path=path, people=[person], props=[box], duration=16.0)
    sits = [
        Situation("robot_alone", 0.5, "the UR3 and the fixtures, nobody near"),
        Situation("arm_reaching", 6.5, "a person's arm reaches into the robot's workspace"),
        Situation("box_placed", 10.5, "a box put down on the table"),
    ]
    return scene, sits, ("Oščádal 2022: UR3 workstation with fixtures, four RealSense D435, in a 7 x 7 m room; "
                         "an arm and a box enter")


def _fr3_cell(rig):
    wps = np.loadtxt(cell_path_file("fr3-cell"), delimiter=",", comments="#", ndmin=2)
    path = JointPath([(0.0, wps[0]), (3.0, wps[1]), (6.0, wps[0])])      # the path franky runs, looped
    face = math.atan2(0.5, -0.9)                                          # towards the robot's base
    keys = [
        Key(3.0, (3.0, -2.9), math.atan2(2.4, -2.1)),
        Key(6.0, (0.9, -0.5), face),                  # walks in towards the path's -y end
        Key(9.0, (0.9, -0.5), face),                  # stands at its edge
        Key(12.0, (3.0, -2.9), -math.pi / 4),         # and leaves
    ]
    person = Person("operator", keys, floor_z=0.0, present=(3.0, 12.5))
    scene = Scene(rig.objects, robot=rig.robot, robot_path=path, people=[person], duration=22.0)
    sits = [
        Situation("robot_alone", 2.0, "the FR3 swinging along its path, nobody in the cell"),
        Situation("approach", 4.5, "a person walks towards the robot's path"),
        Situation("at_path", 7.5, "the person stands at the edge of the robot's path"),
        Situation("gone", 16.0, "the person has left"),
    ]
    return scene, sits, ("Franka FR3 (franky-sim's model) on a workbench, two RealSense D435 on tripods; a person "
                         "walks towards its path, stands there and leaves")


# --------------------------------------------------------------- c-arm room
CARM_SETUPS: dict[str, tuple[CArmPose, str]] = {
    "setup1": (CArmPose.degrees(), "frontal, head position"),
    "setup2": (CArmPose.degrees(larm=90.0, longitudinal=-0.5), "side position (L-arm 90°), over the abdomen"),
    "setup3": (CArmPose.degrees(larm=90.0, longitudinal=0.1), "side position (L-arm 90°), over the chest"),
    "setup4": (CArmPose.degrees(propeller=60.0), "LAO 60° (propeller)"),
    "setup5": (CArmPose.degrees(larm=70.0, propeller=-30.0, longitudinal=-0.3), "L-arm 70°, RAO 30°"),
    "setup6": (CArmPose.degrees(carc=30.0), "cranial 30° (C-arc)"),
}
SETUP_PERIOD = 10.0  # setup k holds for t in [(k-1)·10, k·10)


def patient_primitives(x_head: float = 0.32, table_top: float = 0.90) -> list[Primitive]:
    """A patient lying on the back along x, head towards +x, on a table top at ``table_top``."""
    z = table_top + 0.155
    return [
        Sphere(radius=0.11, world_from_local=pose(t=[x_head, 0.0, table_top + 0.115]), name="patient/head"),
        Capsule.between([x_head - 0.25, 0.0, z], [x_head - 0.80, 0.0, z], 0.15, name="patient/torso"),
        Capsule.between([x_head - 0.85, 0.09, table_top + 0.08], [x_head - 1.75, 0.09, table_top + 0.07], 0.07,
                        name="patient/left_leg"),
        Capsule.between([x_head - 0.85, -0.09, table_top + 0.08], [x_head - 1.75, -0.09, table_top + 0.07], 0.07,
                        name="patient/right_leg"),
        Capsule.between([x_head - 0.30, 0.21, table_top + 0.06], [x_head - 0.85, 0.22, table_top + 0.05], 0.045,
                        name="patient/left_arm"),
        Capsule.between([x_head - 0.30, -0.21, table_top + 0.06], [x_head - 0.85, -0.22, table_top + 0.05], 0.045,
                        name="patient/right_arm"),
    ]


def _carm_room(rig):
    carm = CArm(rail_origin=(0.0, 0.0))
    setups = list(CARM_SETUPS.items())
    path = JointPath([(i * SETUP_PERIOD, p.check().as_array()) for i, (_, (p, _)) in enumerate(setups)],
                     interp="step")
    T = [i * SETUP_PERIOD for i in range(len(setups))]
    up, down = math.pi / 2, -math.pi / 2
    # (x, y, heading, left target, right target) per setup
    doctor = [
        ((-0.35, -0.68), up, (-0.45, -0.12, 1.12), (-0.25, -0.12, 1.14)),
        ((-0.30, -0.68), up, None, (-0.15, -0.15, 1.14)),
        ((-0.75, -0.68), up, (-0.80, -0.12, 1.10), (-0.6, -0.12, 1.12)),
        ((-0.75, 0.68), down, (-0.6, 0.12, 1.12), (-0.8, 0.12, 1.10)),
        ((-0.9, -0.68), up, None, (-0.75, -0.15, 1.10)),
        ((-0.40, -0.68), up, (-0.5, -0.12, 1.12), None),
    ]
    nurse1 = [((-1.2, 0.75), down, None, None), ((-1.2, 0.75), down, None, (-1.15, 0.2, 1.0)),
              ((-1.35, -0.7), up, None, None), ((-1.3, -0.7), up, None, None),
              ((-1.2, 0.8), down, None, None), ((-1.3, 0.75), 0.0, None, None)]
    nurse2 = [((0.9, -1.3), math.pi * 0.75, None, None), ((1.1, 0.9), -math.pi * 0.75, None, None),
              ((0.5, -1.4), up, None, None), ((1.2, 1.0), -math.pi * 0.75, None, None),
              ((1.3, 1.1), -math.pi * 0.75, None, None), ((0.9, -1.35), up, None, None)]

    def person(name, rows, shape):
        keys = [Key(t, xy, h, l, r) for t, (xy, h, l, r) in zip(T, rows)]
        return Person(name, keys, shape=shape, floor_z=0.0, interp="step")

    people = [person("doctor", doctor, BodyShape(height=1.82)),
              person("nurse1", nurse1, BodyShape(height=1.68, torso_width=0.34)),
              person("nurse2", nurse2, BodyShape(height=1.72))]
    static = list(rig.objects) + patient_primitives()
    scene = Scene(static, robot=carm, robot_path=path, people=people, duration=len(setups) * SETUP_PERIOD)
    sits = [Situation(name, t + SETUP_PERIOD / 2, desc) for t, (name, (_, desc)) in zip(T, setups)]
    return scene, sits, ("Hamersma 2011: 4 x 4 x 2.5 m intervention room, ceiling C-arm (the machine), "
                         "patient, doctor, two nurses, 21 ToF cameras; six setups")


_BUILDERS: dict[str, Callable] = {
    "flacco-walls": _flacco_walls,
    "flacco-cell": _flacco_cell,
    "ur3-cell": _ur3_cell,
    "c-arm-room": _carm_room,
    "fr3-cell": _fr3_cell,
}
