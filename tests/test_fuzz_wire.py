"""Property-based tests of the decoders of outside input of the distributed mode (R35):
signed envelopes, the server's settings JSON, the registry file, and the mutation fuzzer
(``depthguard fuzz``) on every target with a few hundred cases (the command runs ≥ 10,000).
The wire format's own properties are in ``test_distributed_wire.py``.

Truth: a signature is bound to the exact bytes signed (any change must be refused); a
refused input changes nothing stored (compared before / after)."""

import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from depthguard.distributed.registry import Registry
from depthguard.distributed.server import FusionServer
from depthguard.transport import wire
from depthguard.transport.auth import AuthError, Signer, Verifier
from depthguard.transport.keys import init_authority, issue_node, load_identity


@pytest.fixture(scope="module")
def node_identity(tmp_path_factory):
    d = tmp_path_factory.mktemp("pki")
    init_authority(d / "ca")
    issue_node("cam0", d / "ca", d / "cam0")
    return load_identity(d / "cam0")


@pytest.fixture(scope="module")
def envelope(node_identity):
    msg = wire.update_request(1, 5, 1.0, 0.02, np.array([[1, 2, 3]]), np.array([4]))
    env, _ = Signer(node_identity).seal(msg, "depthguard/update")
    return env


def test_envelope_roundtrip_and_binding(node_identity, envelope):
    v = Verifier(node_identity.ca_cert)
    got = v.open(envelope, "depthguard/update")
    assert (got.role, got.name) == ("depthguard-node", "cam0")
    assert wire.decode(got.message).unit_id == 1
    with pytest.raises(AuthError, match="replayed"):
        v.open(envelope, "depthguard/update")
    with pytest.raises(AuthError, match="bad signature"):
        Verifier(node_identity.ca_cert).open(envelope, "depthguard/init")     # moved to another key
    with pytest.raises(AuthError, match="bad signature"):                      # as the answer to a request
        Verifier(node_identity.ca_cert).open(envelope, "depthguard/update", reply_to=b"x" * 16)
    with pytest.raises(AuthError, match="outside the 0.001 s window"):
        import time
        time.sleep(0.01)
        Verifier(node_identity.ca_cert, window_s=0.001).open(envelope, "depthguard/update")


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(pos=st.integers(0, 10_000), val=st.integers(1, 255))
def test_any_changed_byte_of_an_envelope_is_refused(node_identity, envelope, pos, val):
    b = bytearray(envelope)
    b[pos % len(b)] ^= val
    with pytest.raises(AuthError):
        Verifier(node_identity.ca_cert).open(bytes(b), "depthguard/update")


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.binary(max_size=2000))
def test_random_bytes_are_never_an_envelope(node_identity, data):
    with pytest.raises(AuthError):
        Verifier(node_identity.ca_cert).open(data, "depthguard/update")


_json = st.recursive(st.none() | st.booleans() | st.floats() | st.integers(-10 ** 20, 10 ** 20) | st.text(max_size=8),
                     lambda c: st.lists(c, max_size=6) | st.dictionaries(st.text(max_size=8), c, max_size=4),
                     max_leaves=12)
_names = st.sampled_from(["voxel_size", "threshold", "stale_s", "offset_const", "offset_k", "joints", "epoch", "x"])


@pytest.fixture(scope="module")
def offline_server():
    return FusionServer(["cam0"], wire.Settings())          # not started: its handlers only


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(obj=st.one_of(_json, st.dictionaries(_names, _json, max_size=4)))
def test_settings_json_is_applied_whole_or_refused_without_change(offline_server, obj):
    srv = offline_server
    before = srv.settings
    text = json.dumps(obj)
    try:
        rep = wire.decode(srv._on_settings(wire._frame(wire.MsgType.SETTINGS_REQ, text.encode())))
    except wire.WireError as exc:            # not a JSON object: refused before any setting is read
        assert str(exc) and srv.settings == before and not isinstance(obj, dict)
        return
    if rep.type == wire.MsgType.ERROR_REP:
        assert rep.text and srv.settings == before
    else:
        assert isinstance(obj, dict) and srv.settings.epoch == before.epoch + 1
        for k, v in obj.items():                          # every value asked for is the value now
            got = getattr(srv.settings, k)
            if k == "joints":
                assert got == tuple(float(q) for q in v)
            elif not (isinstance(v, float) and math.isnan(v)):
                assert abs(got - v) <= 1e-9 * max(1.0, abs(v))


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.one_of(st.binary(max_size=200), _json.map(lambda o: json.dumps(o).encode()),
                      st.dictionaries(st.text(max_size=6), _json, max_size=3).map(
                          lambda u: json.dumps({"version": 1, "units": u}).encode())))
def test_registry_file_loads_or_is_refused_untouched(tmp_path, data):
    p = tmp_path / "reg.json"
    p.write_bytes(data)
    try:
        reg = Registry(p)
    except ValueError as exc:
        assert str(exc).startswith(f"registry {p}")
    else:
        ids = reg.as_dict()
        assert all(isinstance(i, int) and i >= 1 for i in ids.values()) and len(set(ids.values())) == len(ids)
    assert p.read_bytes() == data


@pytest.mark.slow
def test_fuzzer_finds_no_crash_in_any_target():
    from depthguard.distributed.fuzz import TARGETS, run

    results = run(cases=300, seed=7)
    assert [r.target for r in results] == list(TARGETS)
    for r in results:
        assert r.cases == 300 and r.accepted + r.rejected == 300, (r.target, r.crash_examples[:1])
        assert r.crashes == 0
        assert r.rejected > 0        # the mutations do reach the refusals
