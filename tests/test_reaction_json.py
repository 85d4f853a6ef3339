"""The log line's encoder (runtime.reaction_json, issue 29): byte for byte ``json.dumps(r.to_dict(),
allow_nan=False)`` — the record of docs/MONITOR.md — on reactions drawn at random over the record's
whole range (no obstacle, cannot judge, watch points, SSM terms, a policy's terms and record,
reasons, cameras before their first frame, values that round to -0.0 or print in exponent form),
and the same error where the record has none to give."""

import json
import math

import numpy as np
import pytest

from depthguard.control.policy import Part
from depthguard.runtime.reaction_json import reaction_json
from depthguard.runtime.result import CameraStatus, Reaction
from depthguard.runtime.sinks import JsonlLog


def _value(rng, scale=1.0, tiny=True):
    kind = rng.integers(0 if tiny else 2, 8)
    if kind == 0:
        return float(rng.choice([0.0, -0.0, 1.0, -1.0, 0.5e-6, -0.5e-6, 1.5e-6, 2.5e-7, 1e-5, 123456.7654321]))
    if kind == 1:
        return float(rng.normal() * 1e-5)            # exponent form after rounding
    return float(rng.normal() * scale)


def _reaction(rng, ssm: bool, part: bool, tiny: bool = True) -> Reaction:
    global _value
    if not tiny:                                     # ordinary values only: the fast path's lines
        value = _value
        _value = lambda rng, scale=1.0: value(rng, scale, tiny=False)   # noqa: E731
        try:
            return _reaction(rng, ssm, part, True)
        finally:
            _value = value
    m_cp = int(rng.integers(1, 10))
    n_watch = int(rng.integers(0, 3))
    m = m_cp + n_watch
    names = tuple(f"p{i}\u00e9" if i % 3 == 0 else f"cp_{i}" for i in range(m))
    D = np.array([rng.choice([math.inf, _value(rng, 0.3)]) for _ in range(m)])
    V = np.array([[_value(rng) for _ in range(3)] for _ in range(m)])
    obs = rng.random(m) < 0.8
    cams = {}
    for c in range(int(rng.integers(1, 5))):
        age = rng.choice([math.inf, abs(_value(rng, 0.05))])
        cams[f"cam{c}"] = CameraStatus(float(age), str(rng.choice(["fresh", "stale", "waiting"])),
                                       int(rng.integers(0, 500)), int(rng.integers(0, 3)), 0.0)
    reasons = {} if rng.random() < 0.6 else {"stale:cam0": "camera cam0: no frame for more than 100 ms - \"stale\"",
                                             "unobserved:cp_1": "control point cp_1 is not observed (R26)"}
    parts = {}
    terms = None
    if ssm:
        terms = np.array([[_value(rng) for _ in range(13)] for _ in range(m_cp)])
        parts["ssm"] = Part(scale=_value(rng), terms=terms, record={})
    if part:
        parts["mine"] = Part(scale=0.25, stop=bool(rng.random() < 0.5),
                             terms=np.array([[_value(rng), _value(rng)] for _ in range(m_cp)]),
                             term_names=("a", "b\u00fc"), record={"near": True, "x": 0.1234567})
    return Reaction(t=float(rng.random() * 100), override=float(rng.random()),
                    repulsion=np.array([_value(rng) for _ in range(3)]), qd_min=-np.ones(6), qd_max=np.ones(6),
                    names=names, distance=D, direction=V, observed=obs, is_watch=np.arange(m) >= m_cp,
                    reasons=reasons, cameras=cams, joints_age_s=float(rng.choice([math.inf, _value(rng, 0.01)])),
                    q=np.array([_value(rng, 2.0) for _ in range(6)]), reaction_mode="both" if ssm else "repulsion",
                    speed_scale=float(rng.random()), protective_stop=bool(rng.random() < 0.2), ssm=terms,
                    ssm_scale=float(rng.random()), parts=parts)


def test_line_equals_the_json_of_the_record():
    from depthguard.runtime.reaction_json import _fast

    rng = np.random.default_rng(29)
    fast = 0
    for k in range(1200):
        r = _reaction(rng, ssm=k % 3 == 1, part=k % 4 == 3, tiny=k % 2 == 0)
        assert reaction_json(r) == json.dumps(r.to_dict(), allow_nan=False), k
        fast += _fast(r) is not None
    assert fast > 500, fast                  # the template's lines, not only the reference path's


def test_what_the_record_refuses_is_refused_the_same(tmp_path):
    rng = np.random.default_rng(7)
    r = _reaction(rng, ssm=True, part=False)
    bad_d = r.distance.copy()
    bad_d[0] = math.nan
    bad_ssm = r.ssm.copy()
    bad_ssm[0, 3] = math.inf
    bad_q = r.q.copy()
    bad_q[2] = math.nan
    for bad in (dict(distance=bad_d), dict(ssm=bad_ssm), dict(q=bad_q)):
        b = Reaction(**{**r.__dict__, **bad})
        with pytest.raises(ValueError) as ref:
            json.dumps(b.to_dict(), allow_nan=False)
        with pytest.raises(ValueError) as ours:
            reaction_json(b)
        assert str(ours.value) == str(ref.value)
    # the log file holds the record's lines
    log = JsonlLog(tmp_path / "log.jsonl")
    rs = [_reaction(rng, ssm=bool(i % 2), part=False) for i in range(20)]
    for x in rs:
        log(x)
    log.close()
    assert (tmp_path / "log.jsonl").read_text().splitlines() == [json.dumps(x.to_dict(), allow_nan=False) for x in rs]


def test_nearest_equals_its_numpy_twin():
    """Reaction.nearest (a loop over the points, asked by the runner every cycle) answers as its twin."""
    rng = np.random.default_rng(3)
    for k in range(500):
        r = _reaction(rng, ssm=False, part=False)
        if k % 7 == 0:
            d = r.distance.copy()
            d[rng.integers(0, len(d))] = rng.choice([math.nan, -math.inf, 0.0])
            r = Reaction(**{**r.__dict__, "distance": d})
        a, b = r.nearest(), r._nearest_numpy()
        assert a[0] == b[0] and (a[1] == b[1] or (math.isnan(a[1]) and math.isnan(b[1]))), k


def test_results_mcap_messages_equal_rosbags_serialisation():
    """issue 29: the results file's per-cycle messages written directly (runtime.reaction_cdr) are
    byte for byte what rosbags serialises from the message objects McapResults builds."""
    from types import SimpleNamespace

    from depthguard.runtime.mcap_results import McapResults, _register
    from depthguard.runtime.reaction_cdr import float64_cdr, reaction_cdr
    from depthguard.runtime.reaction_cdr_fill import _layouts, reaction_cdr_filled
    from depthguard.transport import ros_messages as rosmsg

    _register()
    rng = np.random.default_rng(31)
    me = SimpleNamespace(frame_id="world")
    for k in range(300):
        r = _reaction(rng, ssm=False, part=False)
        r = Reaction(**{**r.__dict__, "t": abs(r.t),
                        "cameras": {} if k % 17 == 0 else r.cameras,            # empty sequences too
                        "qd_min": rng.normal(size=6), "qd_max": rng.normal(size=6)})
        if k % 13 == 0:
            r = Reaction(**{**r.__dict__, "names": (), "distance": np.zeros(0), "direction": np.zeros((0, 3)),
                            "observed": np.zeros(0, bool), "is_watch": np.zeros(0, bool)})
        truth = rosmsg.serialize(McapResults.reaction_msg(me, r))
        assert reaction_cdr(r, "world") == truth, k
        assert reaction_cdr_filled(r, "world") == truth, k                    # the compiled fill, twice:
        assert reaction_cdr_filled(r, "world") == truth, k                    # its layout made, then reused
        T = rosmsg.TYPESTORE.types
        assert float64_cdr(r.override) == rosmsg.serialize(T[rosmsg.MSG["Float64"]](data=float(r.override)))


def test_results_mcap_markers_equal_rosbags_serialisation():
    """issue 29: the markers written directly (runtime.reaction_cdr.markers_cdr) are byte for byte
    what rosbags serialises from the MarkerArray McapResults.markers_msg builds: spheres of every
    colour, arrows, watch points known and unknown, no points at all, at many alignments."""
    from types import SimpleNamespace

    from depthguard.runtime.mcap_results import McapResults
    from depthguard.transport import ros_messages as rosmsg

    rng = np.random.default_rng(37)
    for k in range(200):
        r = _reaction(rng, ssm=False, part=False)
        r = Reaction(**{**r.__dict__, "t": abs(r.t) + (k % 5) * 1e-9})
        if k % 11 == 0:
            r = Reaction(**{**r.__dict__, "names": (), "distance": np.zeros(0), "direction": np.zeros((0, 3)),
                            "observed": np.zeros(0, bool), "is_watch": np.zeros(0, bool)})
        m_cp = int(np.count_nonzero(~r.is_watch))
        cps = rng.normal(size=(m_cp + int(rng.integers(0, 3)), 3))
        robot = SimpleNamespace(control_points=[SimpleNamespace(radius=float(x)) for x in rng.random(len(cps)) * 0.05],
                                control_point_positions=lambda q, cps=cps: cps)
        watch = {n: rng.normal(size=3) for n in r.names[m_cp:] if rng.random() < 0.7}
        me = McapResults.__new__(McapResults)
        me.robot, me._watch, me.frame_id = robot, watch, "world" if k % 3 else "base_link_x"
        assert me.markers_cdr(r) == rosmsg.serialize(me.markers_msg(r)), k


def test_made_reactions_are_the_constructed_ones():
    """issue 29: Reaction.made / CameraStatus.made (the control step's) give the object the frozen
    dataclass's constructor gives: equal, same fields, still frozen, and the same log line."""
    import dataclasses

    rng = np.random.default_rng(41)
    for k in range(50):
        r = _reaction(rng, ssm=k % 2 == 0, part=k % 3 == 0)
        fields = {f.name: getattr(r, f.name) for f in dataclasses.fields(Reaction)}
        fields["cameras"] = {c: CameraStatus.made(s.age_s, s.state, s.frames, s.refused, s.stamp)
                             for c, s in r.cameras.items()}
        m = Reaction.made(fields)
        assert m == Reaction(**fields) and vars(m) == vars(Reaction(**fields))
        assert all(c == CameraStatus(**vars(c)) for c in m.cameras.values())
        assert reaction_json(m) == json.dumps(r.to_dict(), allow_nan=False)
        with pytest.raises(dataclasses.FrozenInstanceError):
            m.t = 1.0


def test_tiny_numbers_take_the_template_path():
    """The numbers that print in exponent form (0 < |round(x, 6)| < 1e-4) and those ending in
    ``0.0000dd`` inside a larger one are written by the template, equal to the record's json."""
    from depthguard.runtime.reaction_json import _compiled, _fast

    rng = np.random.default_rng(43)
    for k in range(300):
        r = _reaction(rng, ssm=k % 2 == 0, part=False, tiny=False)
        x = float(rng.choice([3.2e-05, -1e-06, 9.9e-05, 1e-05, 10.000032, -7.000001, 1.2345e-05]))
        r = Reaction(**{**r.__dict__, "repulsion": np.array([x, -x, x / 3])})
        line = _fast(r)
        assert line is not None and line == json.dumps(r.to_dict(), allow_nan=False), (k, x)
        assert _compiled(r) == line, (k, x)              # the compiled writer's too


def test_compiled_line_equals_the_json_of_the_record():
    """issue 29: the compiled writer (runtime.reaction_text.encode_line) writes the record's json
    for every reaction whose policies add no terms or record of their own (SSM terms or not,
    no obstacle, cannot judge, watch points, reasons, cameras before their first frame, values
    that round to -0.0, print in exponent form or sit on a rounding tie), and leaves the others
    (a NaN, an infinite term, a number of 1e9) to the reference path."""
    from depthguard.runtime.reaction_json import _compiled

    rng = np.random.default_rng(53)
    done = 0
    for k in range(1500):
        r = _reaction(rng, ssm=k % 3 == 1, part=False, tiny=k % 2 == 0)
        if k % 5 == 0:                               # ties of the 7th decimal, both signs
            x = (2 * int(rng.integers(-10**6, 10**6)) + 1) / 128      # x * 1e6 = k + 1/2 exactly
            r = Reaction(**{**r.__dict__, "repulsion": np.array([x, -x, (int(rng.integers(0, 10**6)) + 0.5) / 1e6]),
                            "t": 1.0078125})
        line = _compiled(r)
        assert line == json.dumps(r.to_dict(), allow_nan=False), k
        done += 1
    assert done == 1500
    r = _reaction(rng, ssm=True, part=False)
    for bad in (dict(q=np.array([math.nan] * 6)), dict(repulsion=np.array([1e9, 0.0, 0.0])),
                dict(ssm=np.full_like(r.ssm, math.inf)), dict(joints_age_s=math.nan)):
        assert _compiled(Reaction(**{**r.__dict__, **bad})) is None, bad
    r = _reaction(rng, ssm=False, part=True)         # a policy's own terms: the template's
    assert _compiled(r) is None and reaction_json(r) == json.dumps(r.to_dict(), allow_nan=False)


def test_compiled_number_equals_repr_of_round():
    """runtime.reaction_text's number is ``repr(round(x, 6))`` (its twin): ties of the 7th decimal
    (half to even on the exact binary value), the floats beside them, exponent forms, -0.0,
    the largest and smallest magnitudes it takes, and what it refuses (None)."""
    from depthguard.runtime.reaction_text import num_text, num_text_reference

    rng = np.random.default_rng(59)
    scale = rng.choice([1e-8, 1e-7, 1e-6, 1e-5, 1e-4, 1e-2, 1.0, 1e3, 1e6, 1e8], size=40000)
    xs = list(rng.normal(size=40000) * scale)
    # exact ties are the odd multiples of 1/128 (x * 1e6 = k + 1/2); beside them, the nearest floats
    # to a decimal tie (k + 1/2) / 1e6, which the product must not round onto one
    ties = np.array([(2.0 * float(j) + 1.0) / 128 for j in rng.integers(-64 * 10**9, 64 * 10**9, 4000)]
                    + [(2 * j + 1) / 128 for j in range(-300, 300)]
                    + [(float(k) + 0.5) / 1e6 for k in rng.integers(-10**15, 10**15, 4000)]
                    + [(k + 0.5) / 1e6 for k in range(-2000, 2000)])
    xs += list(ties) + list(np.nextafter(ties, np.inf)) + list(np.nextafter(ties, -np.inf))
    xs += [0.0, -0.0, 5e-7, -5e-7, 1.5e-6, 2.5e-7, 1e-5, 9.99995e-5, 9.9995e-5, 1e-4, 5e-324, -1e-300,
           999999999.9999999, 1e9, -1e9, math.inf, -math.inf, math.nan]
    for x in xs:
        assert num_text(float(x)) == num_text_reference(float(x)), repr(x)


def test_reasons_that_change_every_cycle_share_one_compiled_layout():
    """issue 29: an SSM reason's sentence carries the cycle's distances, so nearly every line has
    reasons of its own (2,067 sets in 3,818 cycles of fr3-cell); the compiled writer keeps one
    program per layout and splices the reasons in — each line still the record's json, a sentence
    holding the splice's marker byte (JSON-escaped) included."""
    from depthguard.runtime import reaction_json as rjson

    rng = np.random.default_rng(7)
    base = _reaction(rng, ssm=True, part=False, tiny=False)
    rjson._programs.clear()
    for k in range(300):
        d = float(rng.random() * 2)
        reasons = {f"ssm:{base.names[0]}": f"protective stop (R33): control point at {d:.3f} m",
                   "odd\x01key": f"a sentence with \x01 inside, {k}"} if k % 4 else {}
        r = Reaction(**{**base.__dict__, "reasons": reasons})
        line = rjson._compiled(r)
        assert line == json.dumps(r.to_dict(), allow_nan=False), k
    assert len(rjson._programs) == 1


def test_wall_clock_stamps_take_the_compiled_line():
    """issue 29: with a live source the run's clock is the wall clock (~1.8e9 s), beyond the compiled
    numbers' range; the compiled writer still writes the line, the record's json byte for byte
    (``t`` as ``repr(round(t, 6))``, ties of the 7th decimal and whole seconds included), so a live
    run's 500 lines a second do not all go through ``json.dumps``."""
    from depthguard.runtime.reaction_json import _compiled

    rng = np.random.default_rng(11)
    base = _reaction(rng, ssm=True, part=False, tiny=False)
    stamps = [1795750609.947228, 1795750609.0, 1e9, -1.5e9, 9.99e9 + 0.1234565] + list(1.7e9 + rng.random(300) * 1e8)
    for t in stamps:
        r = Reaction(**{**base.__dict__, "t": float(t)})
        line = _compiled(r)
        assert line is not None and line == json.dumps(r.to_dict(), allow_nan=False), t
