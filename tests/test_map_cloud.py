"""The map out (R37, issue 30): the free-space map's occupied and unknown voxels as a
``sensor_msgs/PointCloud2`` in the results MCAP, read back with ``mcap-ros2-support`` (not
depthguard's reader, not rosbags) and compared with the map the monitor held."""

from __future__ import annotations

import numpy as np

from depthguard.filtering.expected import ExpectedDepth
from depthguard.runtime.free_space_map import RuntimeFreeSpace
from depthguard.runtime.mcap_results import McapResults
from depthguard.runtime.sinks import SinkFanout
from depthguard.sim import load_cell
from depthguard.sources.simulated import SimSource


def test_obstacle_cloud_in_the_results_mcap_equals_the_map(tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    cell = load_cell("ur3-cell")
    rig = cell.rig
    t = cell.time_of("arm_reaching")
    q = cell.scene.robot_q(t)
    frames = SimSource(cell, seed=1).frames(t)
    rd = {c.id: np.asarray(ExpectedDepth(c, rig.robot, []).robot(q)) for c in rig.cameras}
    space = RuntimeFreeSpace(rig, robot_offset=rig.monitor.robot_offset, robot_padding=rig.monitor.robot_padding)
    snap = space.build({k: f.depth for k, f in frames.items()}, rd, q, {k: t for k in frames})
    # through the fan-out, as `depthguard monitor` holds its mcap: and ros2: sinks (the monitor
    # hands each map to its sinks' write_map; the fan-out passes it on)
    fanout = SinkFanout([McapResults(tmp_path / "results.mcap", rig.robot)])
    fanout.write_map(snap)
    fanout.close()
    assert fanout.errors == []
    with open(tmp_path / "results.mcap", "rb") as fh:
        msgs = list(make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
            topics=["/depthguard/obstacles"]))
    assert len(msgs) == 1
    schema, channel, _, pc = msgs[0]
    assert channel.topic == "/depthguard/obstacles" and schema.name == "sensor_msgs/msg/PointCloud2"
    assert pc.header.frame_id == "world" and abs(pc.header.stamp.sec + pc.header.stamp.nanosec * 1e-9 - t) < 1e-6
    # decode by the message's own field table (offset, datatype 7 = FLOAT32, 2 = UINT8)
    f = {fd.name: (fd.offset, fd.datatype) for fd in pc.fields}
    assert f["x"][1] == 7 and f["state"][1] == 2 and not pc.is_bigendian
    raw = np.frombuffer(bytes(pc.data), np.uint8).reshape(pc.width * pc.height, pc.point_step)
    xyz = np.stack([raw[:, f[a][0]:f[a][0] + 4].copy().view("<f4")[:, 0] for a in "xyz"], axis=1)
    state = raw[:, f["state"][0]]
    # the truth: the monitor's map, voxel by voxel (every voxel not free and not the robot's body)
    g = snap.grid
    ijk = np.floor((xyz - g.lo) / g.voxel_size).astype(int)
    got = np.zeros(g.shape, np.uint8)
    got[tuple(ijk.T)] = state
    want = np.where(snap.machine, 0, snap.state)
    assert np.array_equal(got, want)
    assert {1, 2} <= set(np.unique(state).tolist())          # both kinds are there and told apart
    assert len(state) == np.count_nonzero(want)
