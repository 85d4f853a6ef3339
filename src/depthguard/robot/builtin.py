"""Built-in robots and :func:`load_robot` (R9, R14, R16).

``lwr4`` — KUKA LWR IV (Flacco et al. 2014, 2015): 7 revolute joints,
standard DH (all ``a = 0``)::

    i      1      2      3      4      5      6      7
    d   0.3105    0     0.40    0     0.39    0    0.078   m
    α    π/2   −π/2   −π/2    π/2    π/2   −π/2     0

so at ``q = 0`` the arm stands straight up with the flange 1.1785 m above
the base; joint 2 turns about −y, joint 4 about +y, joint 6 about −y (as in
the KUKA/ISIR ``lwr_description`` URDF). Limits ±170° (joints 1, 3, 5, 7)
and ±120° (2, 4, 6); velocity limits 112.5 °/s, joint 5 180 °/s (the LWR 4+
data sheet values used by that URDF). Link geometry: capsules of radius
0.04–0.07 m along the links (the real housings are about 0.13 m across),
with the joint housings at 0.102, 0.3105, 0.502, 0.7105, 0.902, 1.1005 m
(q = 0). Nine control points (Flacco 2015 uses 9): flange, wrist, three on
the forearm, elbow, three on the upper arm.

``ur3`` — Universal Robots UR3 from example-robot-data's
``ur_description/urdf/ur3_robot.urdf`` with its STL collision meshes
(read from the installed package, never downloaded). Root link ``world`` =
``base_link``. Capsules were sized to cover the collision meshes (checked by
the tests on vertices and surface samples). The standard UR3 DH table
(Oščádal et al. 2022) is :data:`UR3_DH`; its frame 0 is the URDF's ``base``
link, i.e. ``base_link`` turned by ``Rz(π)`` (see :func:`ur3_dh`).

``fr3`` — Franka Research 3, from the ``fr3.urdf`` and collision STLs that the simulator
``franky-sim`` (PyPI, test extra; Franka's ``franka_description``, Apache-2.0) ships, found
with importlib when the model is first asked for (nothing is copied into this package; where
franky-sim is absent, one sentence says so). Chain root ``base`` to the hand's TCP
(``fr3_hand_tcp``, 0.1034 m past the flange); capsules fitted to each link's collision mesh
and control points as for any URDF (:func:`robot_from_urdf`: the TCP and each moving link's
capsule centre); home = franky-sim's start pose ``(0, 0, 0, -1.57, 0, 1.57, 0.785)`` rad.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

from depthguard.geometry import Capsule
from depthguard.robot.capsules import LinkCapsule, fit_capsule
from depthguard.robot.chain import Chain, forward_numpy
from depthguard.robot.dh import DHRow, dh_links
from depthguard.robot.model import ControlPoint, RobotModel
from depthguard.robot.urdf import example_robot_data_dir, parse_urdf
from depthguard.transforms import invert_rigid, pose, rot_z

__all__ = ["LWR4_DH", "UR3_DH", "lwr4", "ur3", "ur3_dh", "ur3_urdf_path", "fr3_urdf_path", "load_robot",
           "available_robots", "robot_from_urdf"]

_PI2 = np.pi / 2
_DEG = np.pi / 180

LWR4_DH = tuple(
    DHRow(d=d, a=0.0, alpha=al, lower=-lim * _DEG, upper=lim * _DEG, vmax=v * _DEG)
    for d, al, lim, v in [(0.3105, _PI2, 170, 112.5), (0.0, -_PI2, 120, 112.5), (0.40, -_PI2, 170, 112.5),
                          (0.0, _PI2, 120, 112.5), (0.39, _PI2, 170, 180.0), (0.0, -_PI2, 120, 112.5),
                          (0.078, 0.0, 170, 112.5)])

# UR3 standard DH (Oščádal et al. 2022; Universal Robots' published parameters).
# Limits and velocities as in the example-robot-data URDF.
UR3_DH = tuple(
    DHRow(d=d, a=a, alpha=al, lower=-lim, upper=lim, vmax=v)
    for d, a, al, lim, v in [(0.1519, 0.0, _PI2, 2 * np.pi, 2.16), (0.0, -0.24365, 0.0, 2 * np.pi, 2.16),
                             (0.0, -0.21325, 0.0, np.pi, 3.15), (0.11235, 0.0, _PI2, 2 * np.pi, 3.2),
                             (0.08535, 0.0, -_PI2, 2 * np.pi, 3.2), (0.0819, 0.0, 0.0, 2 * np.pi, 3.2)])

# LWR4 geometry at q = 0 (arm along +z): (link, z_from, z_to, radius) in metres.
_LWR4_SEGMENTS = [
    ("base", 0.07, 0.102, 0.07),
    ("link1", 0.102, 0.3105, 0.07),
    ("link2", 0.3105, 0.502, 0.07),
    ("link3", 0.502, 0.7105, 0.07),
    ("link4", 0.7105, 0.902, 0.07),
    ("link5", 0.902, 1.1005, 0.065),
    ("link6", 1.1005, 1.1005, 0.07),
    ("link7", 1.1285, 1.1385, 0.04),
]
# (name, link, height at q = 0, radius)
_LWR4_CPS = [
    ("ee", "link7", 1.1785, 0.04),
    ("wrist", "link6", 1.1005, 0.07),
    ("forearm_3", "link5", 1.02, 0.065),
    ("forearm_2", "link5", 0.93, 0.065),
    ("forearm_1", "link4", 0.82, 0.07),
    ("elbow", "link4", 0.7105, 0.07),
    ("upperarm_3", "link3", 0.62, 0.07),
    ("upperarm_2", "link3", 0.53, 0.07),
    ("upperarm_1", "link2", 0.43, 0.07),
]

# UR3 capsules in link frames: (link, a, b, radius), sized to cover the collision STLs.
_UR3_CAPSULES = [
    ("base_link", (0.0, 0.0, 0.040), (0.002, -0.029, 0.033), 0.079),
    ("shoulder_link", (0.0, 0.004, -0.020), (0.0, 0.004, 0.001), 0.070),
    ("upper_arm_link", (0.0, -0.055, 0.0), (0.0, 0.040, 0.0), 0.048),
    ("upper_arm_link", (0.0, 0.0, 0.0), (0.0, 0.0, 0.1985), 0.048),
    ("upper_arm_link", (0.0, -0.033, 0.24365), (0.0, 0.033, 0.24365), 0.044),
    ("forearm_link", (0.0, -0.005, 0.0), (0.0, 0.0235, 0.0), 0.047),
    ("forearm_link", (0.0, 0.0, 0.0), (0.0, 0.0, 0.18), 0.035),
    ("forearm_link", (0.0, -0.029, 0.21325), (0.0, 0.021, 0.21325), 0.040),
    ("wrist_1_link", (0.0, 0.077, -0.007), (0.0, 0.077, 0.012), 0.051),
    ("wrist_2_link", (0.0, -0.009, 0.077), (0.0, 0.0104, 0.077), 0.051),
    ("wrist_3_link", (0.0, 0.0606, -0.005), (0.0, 0.0606, -0.001), 0.040),
    ("ee_link", (-0.015, 0.0, 0.0), (-0.005, 0.0, 0.0), 0.009),
]
_UR3_CPS = [
    ("ee", "tool0", (0.0, 0.0, 0.0), 0.04),
    ("wrist_2", "wrist_2_link", (0.0, 0.0, 0.077), 0.051),
    ("wrist_1", "wrist_1_link", (0.0, 0.077, 0.0), 0.051),
    ("forearm_end", "forearm_link", (0.0, 0.0, 0.19), 0.04),
    ("forearm_mid", "forearm_link", (0.0, 0.0, 0.10), 0.035),
    ("elbow", "forearm_link", (0.0, 0.0, 0.0), 0.047),
    ("upperarm_end", "upper_arm_link", (0.0, 0.0, 0.20), 0.048),
    ("upperarm_mid", "upper_arm_link", (0.0, 0.0, 0.11), 0.048),
]


def _lwr4_model() -> RobotModel:
    chain = Chain(dh_links(list(LWR4_DH), joint_names=[f"a{i}" for i in range(1, 8)]))
    poses0, _, _ = forward_numpy(chain, np.zeros(chain.dof))

    def local(link: str, z: float) -> np.ndarray:
        T = invert_rigid(poses0[chain.link_index(link)])
        return T[:3, :3] @ np.array([0.0, 0.0, z]) + T[:3, 3]

    caps = [LinkCapsule(l, local(l, z0), local(l, z1), r, name=l) for l, z0, z1, r in _LWR4_SEGMENTS]
    meshes = {c.link: Capsule.between(c.a, c.b, c.radius, segments=24).mesh() for c in caps}
    cps = [ControlPoint(n, l, local(l, z), r) for n, l, z, r in _LWR4_CPS]
    # home: shoulder and elbow bent, flange about 0.6 m in front of the base (−x) at 0.6 m height
    q_home = np.array([0.0, 0.6, 0.0, -1.2, 0.0, 0.6, 0.0])
    return RobotModel("lwr4", chain, q_home=q_home, control_points=cps, link_meshes=meshes,
                      capsules=caps, source="builtin:lwr4 (standard DH, Flacco et al.)")


def ur3_urdf_path() -> Path:
    """Path of example-robot-data's ``ur3_robot.urdf`` (``FileNotFoundError`` if not installed)."""
    d = example_robot_data_dir()
    p = None if d is None else d / "robots" / "ur_description" / "urdf" / "ur3_robot.urdf"
    if p is None or not p.is_file():
        raise FileNotFoundError("the UR3 URDF of example-robot-data is not installed "
                                "(pip install example-robot-data)")
    return p


def _ur3_model() -> RobotModel:
    u = parse_urdf(ur3_urdf_path(), tip="tool0")
    chain = Chain(u.links)
    caps = [LinkCapsule(l, np.array(a), np.array(b), r, name=f"{l}/{i}")
            for i, (l, a, b, r) in enumerate(_UR3_CAPSULES)]
    cps = [ControlPoint(n, l, np.array(o), r) for n, l, o, r in _UR3_CPS]
    q_home = np.array([0.0, -_PI2, _PI2, -_PI2, -_PI2, 0.0])
    return RobotModel("ur3", chain, q_home=q_home, control_points=cps, link_meshes=u.meshes,
                      capsules=caps, source=str(u.path))


def ur3_dh(base: np.ndarray | None = None) -> RobotModel:
    """The UR3 as its standard DH chain (no geometry; control point ``ee`` on the flange).

    DH frame 0 is UR's ``base`` frame = the URDF's ``base_link`` turned by
    ``Rz(π)``: with ``base = T_world_base_link @ Rz(π)`` its flange (link
    ``link6``) coincides with the URDF model's ``tool0``.
    """
    chain = Chain(dh_links(list(UR3_DH), joint_names=["shoulder_pan_joint", "shoulder_lift_joint",
                                                      "elbow_joint", "wrist_1_joint", "wrist_2_joint",
                                                      "wrist_3_joint"]))
    if base is None:
        base = pose(rot_z(np.pi))
    return RobotModel("ur3_dh", chain, base=base, q_home=np.array([0.0, -_PI2, _PI2, -_PI2, -_PI2, 0.0]),
                      control_points=[ControlPoint("ee", "link6", np.zeros(3), 0.04)], source="builtin:ur3 DH")


#: franky-sim's start pose of the FR3 (``franky_sim.constants.DEFAULT_INITIAL_JOINT_POS``), rad
FR3_HOME = (0.0, 0.0, 0.0, -1.57, 0.0, 1.57, 0.785)


def fr3_urdf_path() -> Path:
    """Path of franky-sim's ``assets/fr3.urdf`` (``FileNotFoundError``, one sentence, if not installed).
    The package is located, not imported (importing it loads MuJoCo)."""
    import importlib.util

    spec = importlib.util.find_spec("franky_sim")
    p = None if spec is None or not spec.origin else Path(spec.origin).parent / "assets" / "fr3.urdf"
    if p is None or not p.is_file():
        raise FileNotFoundError("the FR3 model comes from the simulator franky-sim, which is not installed "
                                "(pip install franky-sim, or make venv)")
    return p


def _fr3_model() -> RobotModel:
    return robot_from_urdf(fr3_urdf_path(), tip="fr3_hand_tcp", name="fr3", q_home=FR3_HOME)


_BUILTIN = {"lwr4": _lwr4_model, "ur3": _ur3_model, "fr3": _fr3_model}


def available_robots() -> list[str]:
    """Names accepted by :func:`load_robot` besides URDF paths."""
    return sorted(_BUILTIN)


@lru_cache(maxsize=None)
def _builtin(name: str) -> RobotModel:
    return _BUILTIN[name]()


def lwr4(base: np.ndarray | None = None) -> RobotModel:
    return load_robot("lwr4", base=base)


def ur3(base: np.ndarray | None = None) -> RobotModel:
    return load_robot("ur3", base=base)


def robot_from_urdf(path: str | Path, tip: str | None = None, name: str | None = None,
                    q_home=None) -> RobotModel:
    """A model from any URDF: capsules fitted to each link's geometry (:func:`fit_capsule`),
    control points at the tip (index 0) and at the middle of each moving link's capsule;
    ``q_home`` (dof,) rad, default 0 clipped to the limits."""
    u = parse_urdf(path, tip=tip)
    chain = Chain(u.links)
    caps = []
    for ln, m in u.meshes.items():
        a, b, r = fit_capsule(m.vertices)
        caps.append(LinkCapsule(ln, a, b, max(r, 1e-3) + 1e-6, name=ln))
    cps = [ControlPoint("ee", u.tip, np.zeros(3), 0.0)]
    for c in caps:
        if chain.support[chain.link_index(c.link)].any():
            cps.append(ControlPoint(c.link, c.link, 0.5 * (c.a + c.b), c.radius))
    if q_home is None:
        q_home = np.clip(np.zeros(chain.dof), chain.q_min, chain.q_max)
    return RobotModel(name or u.name, chain, q_home=q_home, control_points=cps, link_meshes=u.meshes,
                      capsules=caps, source=str(u.path))


def load_robot(name_or_path: str | Path, base: np.ndarray | None = None, tip: str | None = None) -> RobotModel:
    """A robot by built-in name (:func:`available_robots`) or URDF path, placed at ``base`` (4, 4).

    Unknown names raise ``ValueError`` listing the built-in names; a missing
    URDF raises ``FileNotFoundError``; a broken one ``ValueError``.
    """
    key = str(name_or_path)
    if key in _BUILTIN:
        robot = _builtin(key)
    elif key.lower().endswith((".urdf", ".xml")) or "/" in key or "\\" in key or Path(key).is_file():
        robot = robot_from_urdf(key, tip=tip)
    else:
        raise ValueError(f"unknown robot {key!r}; built-in robots are {available_robots()} "
                         f"(or give the path of a .urdf file)")
    return robot if base is None else robot.with_base(base)
