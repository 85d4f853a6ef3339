"""Small rigs for the distributed tests: cameras of 160 x 120 px around a 1.2 m workspace,
no robot, no scene (the nodes' pattern source needs only the cameras)."""

RIG = """
name: {name}
workspace: {{min: [-0.6, -0.6, 0.0], max: [0.6, 0.6, 1.0]}}
cameras:
{cams}
"""
CAM = """  - id: {id}
    width: 160
    height: 120
    fx: 140.0
    fy: 140.0
    cx: 79.5
    cy: 59.5
    range: [0.2, 6.0]
    pose: {{look_at: {{eye: [{x}, {y}, 1.4], target: [0.0, 0.0, 0.5]}}}}
"""
EYES = [(1.6, 0.1), (-1.6, -0.1), (0.1, 1.6), (-0.1, -1.6)]


def write_rig(path, ids=("cam0", "cam1", "cam2", "cam3"), name="four-cams"):
    """A rig file at ``path`` with one camera per id (at most four), each looking at the workspace."""
    if len(ids) > len(EYES):
        raise ValueError(f"at most {len(EYES)} cameras")
    cams = "".join(CAM.format(id=c, x=x, y=y) for c, (x, y) in zip(ids, EYES))
    path.write_text(RIG.format(name=name, cams=cams))
    return path


def write_abc_rig(path, ids=("camA", "camB", "camC")):
    """The rig of the certificate tests: cameras camA, camB, camC."""
    return write_rig(path, ids, name="tls-cell")
