"""Write the calibrated rig: the user's file with new camera poses, everything else intact (R2, R34).

The rig's YAML text is parsed into nodes (``yaml.compose``), which know where
in the text they stand; only the text of each recalibrated camera's
``pose:`` value is replaced — by ``{translation: [x, y, z], quaternion:
[x, y, z, w]}`` (m, xyzw) — so comments, order, formatting and every other
field stay as the user wrote them. A header comment says what changed.
Relative ``mesh:`` and ``urdf:`` paths are rewritten when the new file lies
in another folder, so that they still name the same files. The text is
loaded back (:meth:`depthguard.rig.Rig.from_dict`) and checked to give
exactly the new poses before anything is written, and the file is created
exclusively: an existing file is never overwritten.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import yaml

__all__ = ["calibrated_rig_text", "write_calibrated_rig"]


def _get(node, key: str):
    if isinstance(node, yaml.MappingNode):
        for k, v in node.value:
            if isinstance(k, yaml.ScalarNode) and k.value == key:
                return k, v
    return None, None


def _end(node) -> int:
    """Text index just after the last character of ``node`` (a block collection's own end mark
    lies at the next token, past any comment lines: use its last child's)."""
    if isinstance(node, yaml.MappingNode) and not node.flow_style and node.value:
        return _end(node.value[-1][1])
    if isinstance(node, yaml.SequenceNode) and not node.flow_style and node.value:
        return _end(node.value[-1])
    return node.end_mark.index


def _num(x: float) -> str:
    return repr(round(float(x), 12) + 0.0)


def _pose_text(T: np.ndarray) -> str:
    from depthguard.transforms import matrix_to_quat

    t = np.asarray(T, dtype=np.float64)[:3, 3]
    q = matrix_to_quat(np.asarray(T, dtype=np.float64)[:3, :3])
    return ("{translation: [" + ", ".join(_num(v) for v in t) + "], quaternion: ["
            + ", ".join(_num(v) for v in q) + "]}")


def calibrated_rig_text(text: str, poses: dict, src_dir: Path, out_dir: Path, header: str = "") -> str:
    """The rig text ``text`` with the camera poses ``poses`` (camera id -> (4, 4) world_from_camera)
    replaced (module docstring); ``src_dir`` / ``out_dir`` the folders of the old and new file."""
    root = yaml.compose(text)
    if not isinstance(root, yaml.MappingNode):
        raise ValueError("the rig file is not a mapping: cannot write a calibrated copy")
    edits: list[tuple[int, int, str]] = []
    _, cams = _get(root, "cameras")
    found = set()
    for item in (cams.value if isinstance(cams, yaml.SequenceNode) else []):
        _, idn = _get(item, "id")
        cid = idn.value if isinstance(idn, yaml.ScalarNode) else None
        if cid not in poses:
            continue
        found.add(cid)
        key, val = _get(item, "pose")
        new = _pose_text(poses[cid])
        if val is not None and (not isinstance(val, (yaml.MappingNode, yaml.SequenceNode)) or val.flow_style):
            edits.append((val.start_mark.index, _end(val), new))
        elif val is not None:                     # block style: "pose:\n  look_at: ..." -> "pose: {...}"
            edits.append((key.start_mark.index, _end(val), "pose: " + new))
        else:
            raise ValueError(f"camera {cid}: the rig file gives no pose: to replace")
    missing = set(poses) - found
    if missing:
        raise ValueError(f"the rig file has no camera {', '.join(sorted(missing))}")
    if Path(src_dir).resolve() != Path(out_dir).resolve():
        for path_node in _path_nodes(root):
            p = Path(path_node.value)
            if not p.is_absolute():
                new_p = os.path.relpath((Path(src_dir) / p).resolve(), Path(out_dir).resolve())
                edits.append((path_node.start_mark.index, path_node.end_mark.index, yaml.safe_dump(
                    new_p, default_style='"').strip().removesuffix("...").strip()))
    out = text
    for a, b, s in sorted(edits, reverse=True):
        out = out[:a] + s + out[b:]
    if header:
        out = "".join(f"# {line}\n" if line else "#\n" for line in header.splitlines()) + out
    return out


def _path_nodes(root) -> list:
    nodes = []
    _, objs = _get(root, "objects")
    for item in (objs.value if isinstance(objs, yaml.SequenceNode) else []):
        _, m = _get(item, "mesh")
        if isinstance(m, yaml.ScalarNode):
            nodes.append(m)
    _, robot = _get(root, "robot")
    _, urdf = _get(robot, "urdf") if robot is not None else (None, None)
    if isinstance(urdf, yaml.ScalarNode):
        nodes.append(urdf)
    return nodes


def write_calibrated_rig(src: Path, out: Path, poses: dict, header: str = "") -> str:
    """Write ``out`` (must not exist) from rig file ``src`` with the new ``poses``; returns the text.
    The text is loaded back first and must give the new poses and the same cameras, objects and robot."""
    from depthguard.rig import Rig

    src, out = Path(src), Path(out)
    if out.exists():
        raise ValueError(f"--out {out} exists already; calibrate never overwrites a file (choose a new name)")
    if not out.parent.is_dir():
        raise ValueError(f"--out {out}: the folder {out.parent} does not exist")
    text = src.read_text()
    new = calibrated_rig_text(text, poses, src.parent, out.parent, header)
    old_rig = Rig.load(src)
    check = Rig.from_dict(yaml.safe_load(new), source=out)
    if check.camera_ids != old_rig.camera_ids or len(check.objects) != len(old_rig.objects):
        raise RuntimeError("the calibrated rig text lost cameras or objects (a bug): nothing written")
    for c_old, c_new in zip(old_rig.cameras, check.cameras):
        want = poses.get(c_old.id, c_old.world_from_camera)
        if not np.allclose(c_new.world_from_camera, want, atol=1e-9):
            raise RuntimeError(f"camera {c_old.id}: the written pose does not read back (a bug): nothing written")
    with open(out, "x") as fh:            # exclusive: never overwrite
        fh.write(new)
    return new
