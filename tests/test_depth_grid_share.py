"""A camera's share of the depth grid's clearing made off the build (issue 29,
:mod:`depthguard.fusion.depth_grid_share`, R11, R12).

Truth: the same grid without the shares, loaded with the same frames and states, working out
every camera's clearing itself. With the shares the distances, directions and observed flags
are the same bit for bit, cycle by cycle, on cells with one and with three other cameras
(flacco-cell, ur3-cell, with a person in view); the shares' bits equal the build's own where
both evaluated a cell (an exact check of the kernel, not only of the answers); and the
build then evaluates fewer cells itself (the shares are used, not vacuous). A share made with
another state object, or for another grid's tables, is not installed.
"""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.fusion.depth_grid import DepthGridMap
from depthguard.fusion.depth_grid_share import CameraSharer, share_spec
from depthguard.fusion.depth_grid_state import StateMaker, StateOptions, pyramid_levels
from depthguard.robot.volume import robot_volume


def _frames(name: str, person: bool):
    import depthguard.evaluation.bench.fusion_cells as fc

    starts = dict((n, s) for n, s, _ in fc.BUILTIN_WINDOWS + fc.FULL_ONLY_WINDOWS)
    return fc._Frames(*fc._builtin_world(name, starts[name], person, 0), 16)


def _popcount(words: np.ndarray) -> int:
    return int(np.unpackbits(np.ascontiguousarray(words).view(np.uint8)).sum())


@pytest.mark.parametrize("name,person", [("flacco-cell", True), ("ur3-cell", True)])
def test_shares_give_the_builds_own_bits_and_the_same_distances(name, person):
    frames = _frames(name, person)
    rig, cfg, robot = frames.rig, frames.rig.monitor, frames.rig.robot
    cams = list(rig.cameras)
    d_min, d_max = rig.workspace.depth_span(cams[0])

    def grid():
        return DepthGridMap(cams, principal=cams[0].id, d_min=d_min, d_max=d_max, delta_d=cfg.delta_d,
                            principal_bin=cfg.principal_bin)

    with_shares, alone = grid(), grid()
    with_shares.share_requests = True
    opts = StateOptions.of(cfg)
    makers = {c.id: StateMaker(c) for c in cams}
    sharers = {c.id: CameraSharer() for c in cams[1:]}
    specs = {c.id: share_spec(with_shares, c.id) for c in cams[1:]}
    levels = pyramid_levels(max(c.height for c in cams[1:]), max(c.width for c in cams[1:]))
    rho = cfg.query_rho + 0.02
    data = robot.create_data()
    depths, rdepths, states, shares, q_caps = {}, {}, {}, {}, {}
    compared = evaluated_alone = evaluated_with = 0
    for i, (s, cid, depth, rdepth, q) in enumerate(frames.frames):
        cam = rig.camera(cid)
        principal = cid == cams[0].id
        depths[cid], rdepths[cid], q_caps[cid] = depth, rdepth, q
        states[cid] = makers[cid].make(depth, rdepth, opts, cfg.robot_in_others == "free" and not principal,
                                       pyramids=not principal and pyramid_levels(cam.height, cam.width) == levels,
                                       bin=cfg.principal_bin if principal else 1)
        if len(depths) < len(cams):
            continue
        if not principal:                              # as the camera's worker, before the build
            shares[cid] = sharers[cid].make(specs[cid], states[cid],
                                            with_shares.share_request(specs[cid].key[1]))
            if shares[cid] is None:
                del shares[cid]
        caps = robot_volume(robot, list(q_caps.values()), cfg.robot_padding)
        robot.forward(frames.q_at(s + 0.01), data)
        first = with_shares.has_frames is False
        kw = dict(robot_offset=cfg.robot_offset, robot_capsules=caps, invalid=cfg.invalid,
                  robot_in_others=cfg.robot_in_others, changed=None if first else {cid},
                  silhouette_px=cfg.silhouette_px, gap_px=cfg.gap_px, states=dict(states))
        alone.set_frames(depths, rdepths, **kw)
        with_shares.set_frames(depths, rdepths, shares=dict(shares), **kw)
        a = alone.query(data.cp_positions, rho=rho, method=cfg.method).copy()
        b = with_shares.query(data.cp_positions, rho=rho, method=cfg.method).copy()
        np.testing.assert_array_equal(a.distance, b.distance)
        np.testing.assert_array_equal(a.direction, b.direction)
        np.testing.assert_array_equal(a.observed, b.observed)
        if principal or first or cid not in shares:
            continue
        # the share's bits against the build's own, where both evaluated a cell of the new camera
        k = [c.id for c in cams[1:]].index(cid)
        ver = alone._kmemo[0][k]
        sh = shares[cid]
        W = alone.principal.width
        v, u = sh.idx // W, sh.idx % W
        own = alone._kmemo[1][k, v, u] == ver
        both = sh.done[own] & alone._kmemo[2][k, v[own], u[own]]
        assert np.array_equal(sh.clr[own] & both, alone._kmemo[3][k, v[own], u[own]] & both)
        compared += _popcount(both)
        evaluated_alone += _popcount(alone._kmemo[2][k][alone._kmemo[1][k] == ver])
        evaluated_with += _popcount(with_shares._kmemo[2][k][with_shares._kmemo[1][k] == ver]) - _popcount(sh.done)
    assert with_shares.shares_used >= len(frames.frames) // 3 and alone.shares_used == 0
    assert compared > 10_000
    assert evaluated_with < 0.5 * evaluated_alone          # the build left most of it to the shares


def test_a_share_of_another_state_or_another_grid_is_not_installed():
    frames = _frames("flacco-cell", False)
    rig, cfg, robot = frames.rig, frames.rig.monitor, frames.rig.robot
    cams = list(rig.cameras)
    d_min, d_max = rig.workspace.depth_span(cams[0])
    grid = DepthGridMap(cams, principal=cams[0].id, d_min=d_min, d_max=d_max, delta_d=cfg.delta_d,
                        principal_bin=cfg.principal_bin)
    other = DepthGridMap(cams, principal=cams[0].id, d_min=d_min, d_max=d_max, delta_d=cfg.delta_d * 2,
                         principal_bin=cfg.principal_bin)
    opts = StateOptions.of(cfg)
    (s0, c0, d0, r0, _), (s1, c1, d1, r1, q1) = frames.frames[0], frames.frames[1]
    assert c0 == cams[0].id and c1 == cams[1].id
    p0 = StateMaker(cams[0]).make(d0, r0, opts, bin=cfg.principal_bin)
    st = StateMaker(cams[1]).make(d1, r1, opts, pyramids=True)
    twin = StateMaker(cams[1]).make(d1, r1, opts, pyramids=True)        # equal content, another object
    caps = robot_volume(robot, [q1], cfg.robot_padding)

    def request(g):                  # every slice of a 20 x 20 block of columns at the image's centre
        H, W = g.principal.shape
        v, u = np.mgrid[H // 2 - 10:H // 2 + 10, W // 2 - 10:W // 2 + 10]
        want = np.zeros((v.size, (g.n_d + 63) // 64), dtype=np.uint64)
        for gd in range(g.n_d):
            want[:, gd >> 6] |= np.uint64(1 << (gd & 63))
        return (v * W + u).ravel().astype(np.int64), want

    share = CameraSharer().make(share_spec(grid, c1), st, request(grid))
    foreign = CameraSharer().make(share_spec(other, c1), st, request(other))
    assert len(share.idx) == 400 and np.array_equal(share.done, request(grid)[1])
    depths, rdepths = {c0: d0, c1: d1}, {c0: r0, c1: r1}
    kw = dict(robot_capsules=caps, robot_offset=cfg.robot_offset, invalid=cfg.invalid,
              robot_in_others=cfg.robot_in_others, silhouette_px=cfg.silhouette_px, gap_px=cfg.gap_px)
    grid.set_frames(depths, rdepths, states={c0: p0, c1: twin}, shares={c1: share}, **kw)
    assert grid.shares_used == 0
    grid.set_frames(depths, rdepths, states={c0: p0, c1: st}, shares={c1: foreign}, **kw)
    assert grid.shares_used == 0
    grid.set_frames(depths, rdepths, states={c0: p0, c1: st}, shares={c1: share}, **kw)
    assert grid.shares_used == 1
