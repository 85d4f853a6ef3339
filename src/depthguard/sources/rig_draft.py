"""Draft a rig file from a ROS 2 bag: ``depthguard rig from-bag`` (R2, R31).

What the bag decides:

- one camera per depth ``Image`` topic that has a ``CameraInfo`` beside it: its id (from the
  topic's first name, ``/cam0/depth/image_rect_raw`` -> ``cam0``), ``topic:``, size and
  intrinsics (a CameraInfo with distortion is refused, as the bag source refuses it);
- its pose: the TF chain (``/tf_static``, then the first ``/tf`` of each edge) from the base
  frame to the CameraInfo's ``frame_id``, an optical frame (z forward, x right, y down: the
  convention depthguard's cameras use). The base frame is ``--base-frame`` or the root of the
  TF tree that holds the cameras;
- the robot: ``/robot_description`` (written next to the rig as ``<rig>.urdf``) or ``--urdf``,
  with its base pose from TF when its root link is a TF frame.

What it cannot decide is written as a commented field with a sentence, never guessed: the
``workspace`` (required: the rig does not load until it is filled in), each camera's
``range`` (the sensor's datasheet; the loader's default is 0.4..6 m), the ``depth_scale`` of a
camera whose depth is 16-bit (an Image does not say its units: 0.001 m = millimetres by
default, 0.0001 m for a RealSense D405 — a wrong one reads every distance 10 times off), a
camera pose missing from TF, and the robot when the bag has no description and no ``--urdf``
is given.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from depthguard.sources import bag_layouts as layouts
from depthguard.sources.bag import BagError, BagReplay, info_topic
from depthguard.transport import ros_messages as rosmsg

__all__ = ["draft_rig", "tf_tree", "chain"]

#: encodings whose units an Image does not say (the rig's ``depth_scale``)
_SIXTEEN_BIT = {"16UC1", "mono16"}
#: frames that are optical frames (z forward, x right, y down) without the name: the Azure Kinect
#: driver's camera frames are its SDK's camera coordinates
_OPTICAL = {"depth_camera_link", "rgb_camera_link"}


def tf_tree(replay: BagReplay) -> dict[str, tuple[str, np.ndarray]]:
    """``child -> (parent, parent_from_child 4x4)``: /tf_static first, else the first /tf of the edge."""
    edges: dict[str, tuple[str, np.ndarray]] = {}
    for static in (True, False):
        for _stamp, is_static, tr in replay.tf:
            child = tr.child_frame_id.lstrip("/")
            if is_static == static and child not in edges:
                try:
                    edges[child] = (tr.header.frame_id.lstrip("/"), rosmsg.matrix_from_transform(tr.transform))
                except rosmsg.RosMessageError:
                    continue
    return edges


def chain(edges, frame: str, base: str | None) -> tuple[str, np.ndarray] | None:
    """``(base, base_from_frame)`` by walking up from ``frame`` (to the root when ``base`` is None);
    ``None`` when ``base`` is not above ``frame``."""
    T = np.eye(4)
    cur, seen = frame, set()
    while cur != base and cur in edges and cur not in seen:
        seen.add(cur)
        parent, M = edges[cur]
        T = M @ T
        cur = parent
    if base is None or cur == base:
        return cur, T
    return None


def _listing(images: dict) -> str:
    return ", ".join(f"{t} ({'/'.join(sorted(e))})" for t, e in sorted(images.items()))


def _num(v: float) -> str:
    return repr(float(v))


def _matrix_lines(T: np.ndarray, indent: str) -> list[str]:
    rows = [f"{indent}  - [{', '.join(_num(x) for x in row)}]" for row in np.asarray(T)]
    return [f"{indent}matrix:"] + rows


def draft_rig(bag: str | Path, out: str | Path, urdf: str | Path | None = None,
              base_frame: str | None = None) -> tuple[str, list[str]]:
    """Write the draft rig to ``out`` (which must not exist); returns ``(text, notes)``."""
    out = Path(out)
    if out.exists():
        raise BagError(f"--out {out} exists already; choose a new file (a draft never overwrites a rig)")
    replay = BagReplay(bag)
    try:
        return _draft(replay, out, urdf, base_frame)
    finally:
        replay.close()


def _draft(replay: BagReplay, out: Path, urdf, base_frame) -> tuple[str, list[str]]:
    notes: list[str] = []
    edges = tf_tree(replay)
    cams = []
    taken: set[str] = set()
    images = {t: {e.encoding for e in entries} for t, entries in replay.images.items()}
    groups, others = layouts.depth_streams(images)
    if others:
        notes.append(f"not depth (encoding or stream): {', '.join(others)}; not cameras of the draft")
    for _ns, topics in sorted(groups.items()):
        drafted = None
        for topic in topics:
            infos = replay.infos.get(info_topic(topic))
            if not infos:
                notes.append(f"{topic}: no CameraInfo on {info_topic(topic)}; not a camera of the draft")
                continue
            try:
                k = layouts.camera_intrinsics(topic, infos[0][1])
            except rosmsg.RosMessageError as exc:
                notes.append(f"{topic}: {exc}; not a camera of the draft")
                continue
            if drafted is not None:
                notes.append(f"{topic}: the depth of camera {drafted} again (re-projected); not drafted - "
                             f"give it as that camera's topic: (with its intrinsics) to read it instead")
                continue
            cid, base_id, n = layouts.camera_id(topic), layouts.camera_id(topic), 1
            while cid in taken:
                n += 1
                cid = f"{base_id}_{n}"
            taken.add(cid)
            drafted = cid
            cams.append((cid, topic, k, bool(images[topic] & _SIXTEEN_BIT)))
    if not cams:
        raise BagError(f"bag {replay.path}: no depth Image topic with a usable CameraInfo beside it "
                       f"(image topics: {_listing(images) or 'none'}{'; ' + notes[-1] if notes else ''})")
    sixteen_bit = [cid for cid, _t, _k, sixteen in cams if sixteen]
    if sixteen_bit:
        notes.append(f"camera {', '.join(sixteen_bit)}: 16-bit depth, read as millimetres unless you give its "
                     "depth_scale (a RealSense D405 counts 0.1 mm)")
    roots = {chain(edges, k["frame_id"].lstrip("/"), None)[0] for _c, _t, k, _s in cams if k["frame_id"]}
    base = base_frame or (sorted(roots)[0] if len(roots) == 1 else None)
    if base is None and roots:
        notes.append(f"the cameras' TF frames have several roots ({', '.join(sorted(roots))}): give --base-frame")
    lines = [f"# depthguard rig drafted from the ROS 2 bag {replay.path} by `depthguard rig from-bag`.",
             "# Check every value; the commented fields could not be decided from the bag: fill them in.",
             "version: 1", f"name: {re.sub(r'[^A-Za-z0-9_-]', '-', out.stem) or 'rig'}",
             f"description: drafted from {replay.path.name}; world = TF frame {base or '(undecided)'}",
             "# workspace: the box of interest in the world frame, metres (required; not in a bag), e.g.",
             "# workspace: {min: [-1.0, -1.0, 0.0], max: [1.0, 1.0, 2.0]}",
             "cameras:"]
    for cid, topic, k, sixteen in cams:
        lines += [f"  - id: {cid}", f"    topic: {topic}", f"    width: {k['width']}", f"    height: {k['height']}",
                  f"    fx: {_num(k['fx'])}", f"    fy: {_num(k['fy'])}", f"    cx: {_num(k['cx'])}", f"    cy: {_num(k['cy'])}",
                  "    # range: [min, max]  # metres, from the sensor's datasheet (not in a bag; default 0.4..6)"]
        if sixteen:
            lines.append("    # depth_scale: 0.001  # metres per unit of its 16-bit depth (not in a bag; default 0.001 = mm; "
                         "a RealSense D405 writes 0.0001: its SDK's depth units)")
        found = chain(edges, k["frame_id"].lstrip("/"), base) if (base and k["frame_id"]) else None
        if found is None:
            lines += [f"    # pose: the pose of TF frame {k['frame_id'] or '(none)'} in {base or 'the world'} is not in the "
                      "bag's TF; give it (translation + quaternion, matrix or look_at)"]
            notes.append(f"camera {cid}: no TF chain from {base} to {k['frame_id']!r}; its pose is left to fill in")
        else:
            if not k["frame_id"].endswith("optical_frame") and k["frame_id"].lstrip("/") not in _OPTICAL:
                lines.append(f"    # frame {k['frame_id']} is taken as an optical frame (z forward, x right, y down): check")
            lines += ["    pose:"] + _matrix_lines(found[1], "      ")
    lines += _robot_lines(replay, out, urdf, edges, base, notes)
    text = "\n".join(lines) + "\n"
    out.write_text(text)
    return text, notes


def _robot_lines(replay, out: Path, urdf, edges, base, notes) -> list[str]:
    descr = replay.strings.get("/robot_description")
    if urdf is None and descr:
        urdf = out.with_suffix(".urdf")
        if urdf.exists():
            raise BagError(f"{urdf} exists already; the robot description of the bag would overwrite it")
        urdf.write_text(descr[-1])
        notes.append(f"robot: /robot_description written to {urdf}")
    if urdf is None:
        return ["# robot: the bag has no /robot_description: give `urdf: FILE` (or a built-in `name:`)",
                "#   and its base pose in the world frame (not decided here)"]
    lines = ["robot:", f"  urdf: {Path(urdf).resolve() if urdf != out.with_suffix('.urdf') else Path(urdf).name}"]
    root = _urdf_root(Path(urdf))
    found = chain(edges, root, base) if (root and base) else None
    if found is not None:
        lines += ["  base:"] + _matrix_lines(found[1], "    ")
    else:
        lines.append(f"  # base: the pose of the robot's root link {root!r} in the world is not in the bag's TF: give it")
    return lines


def _urdf_root(path: Path) -> str | None:
    import xml.etree.ElementTree as ET

    try:
        tree = ET.parse(path)
    except (ET.ParseError, OSError):
        return None
    links = [e.get("name") for e in tree.getroot().iter("link")]
    children = {c.get("link") for j in tree.getroot().iter("joint") for c in j.iter("child")}
    roots = [n for n in links if n not in children]
    return roots[0] if len(roots) == 1 else None

