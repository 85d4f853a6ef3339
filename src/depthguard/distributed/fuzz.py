"""Fuzzing the decoders and loaders that take outside input (R35): ``depthguard fuzz``.

A mutation fuzzer with no dependency beyond the package: each target starts from
valid inputs (seeds) and feeds the decoder mutated copies — bit flips, byte
overwrites with boundary values, truncation, extension, duplicated and deleted
spans, splices of two seeds, random bytes — and, for the wire format and the signed
envelope, mutations whose CRC / lengths are recomputed so the body parsers are
reached rather than only the frame checks. Per case the property is:

* the decoder returns, or raises ``ValueError`` (or ``FileNotFoundError``) with a
  non-empty sentence — any other exception is a **crash**;
* a rejected input changes nothing stored (the server's settings, a registry file);
* an accepted mutated envelope is impossible (a signature must not verify on bytes
  that differ from what was signed) — such a case is also counted as a crash.

Targets: ``wire`` (:func:`depthguard.transport.wire.decode`), ``envelope``
(:class:`depthguard.transport.auth.Verifier`), ``settings`` (the server's
SETTINGS_REQ JSON), ``registry`` (the registry file), ``rig`` (rig YAML files,
:meth:`depthguard.rig.Rig.load`), ``depth`` (``.npy`` / ``.png`` depth files,
:func:`depthguard.depth_io.read_depth`), ``ros`` and ``bag`` (ROS 2 messages and bag files as the
``bag:`` source reads them, :mod:`depthguard.distributed.fuzz_ros`). :func:`run` returns one :class:`FuzzResult`
per target; the tests run a few hundred cases, the command ≥ 10,000 per target.
"""

from __future__ import annotations

import json
import random
import struct
import tempfile
import time
import traceback
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

__all__ = ["TARGETS", "FuzzResult", "run", "mutate"]

_BOUNDARY = [0x00, 0x01, 0x7F, 0x80, 0xFF]


@dataclass
class FuzzResult:
    """Counts of one target: cases, accepted, rejected (clear error), crashes (with examples)."""
    target: str
    cases: int = 0
    accepted: int = 0
    rejected: int = 0
    crashes: int = 0
    seconds: float = 0.0
    errors: dict = field(default_factory=dict)          # first words of each rejection kind -> count
    crash_examples: list = field(default_factory=list)  # (input bytes, traceback text), at most 5


def mutate(rnd: random.Random, data: bytes, seeds: list[bytes]) -> bytes:
    """One to four random mutations of ``data`` (module docstring)."""
    b = bytearray(data)
    for _ in range(rnd.randint(1, 4)):
        op = rnd.randrange(9)
        n = len(b)
        if op == 0 and n:                                   # bit flip
            i = rnd.randrange(n)
            b[i] ^= 1 << rnd.randrange(8)
        elif op == 1 and n:                                 # boundary byte
            b[rnd.randrange(n)] = rnd.choice(_BOUNDARY)
        elif op == 2 and n:                                 # truncate
            del b[rnd.randrange(n):]
        elif op == 3:                                       # extend with random bytes
            b += rnd.randbytes(rnd.randint(1, 64))
        elif op == 4 and n > 1:                             # delete a span
            i = rnd.randrange(n)
            del b[i:i + rnd.randint(1, 16)]
        elif op == 5 and n > 1:                             # duplicate a span
            i = rnd.randrange(n)
            b[i:i] = b[i:i + rnd.randint(1, 32)]
        elif op == 6 and seeds:                             # splice with another seed
            other = rnd.choice(seeds)
            i, j = rnd.randrange(len(b) + 1), rnd.randrange(len(other) + 1)
            b = b[:i] + bytearray(other[j:])
        elif op == 7 and n >= 4:                            # a 32-bit field set to a boundary value
            i = rnd.randrange(n - 3)
            b[i:i + 4] = struct.pack("<I", rnd.choice([0, 1, 0x7FFFFFFF, 0xFFFFFFFF, n, 2 * n]))
        else:                                               # random bytes
            b = bytearray(rnd.randbytes(rnd.randint(0, 96)))
    return bytes(b)


def _kind(exc: BaseException, work: str) -> str:
    return " ".join(str(exc).replace(work, "<dir>").split()[:3])[:60] or type(exc).__name__


# ------------------------------------------------------------------ targets
def _wire_target(work: Path):
    from depthguard.transport import wire

    rng = np.random.default_rng(0)
    keys = rng.integers(-300, 300, (40, 3))
    seeds = [wire.init_request("cam0", "host/pid1"), wire.init_reply(3, wire.Settings(joints=(0.1, 0.2))),
             wire.update_request(2, 7, 12.5, 0.02, keys, np.arange(40), 0.3), wire.update_reply(wire.Settings(), True),
             wire.error_reply(3, "unit id 9 is not initialised"), wire.status_request(), wire.status_reply({"a": [1, 2]}),
             wire.settings_request(voxel_size=0.05), wire.units_request({"cam0": (4, 1.5), "cam1": (1, 2.0)}),
             wire.units_reply("cam0", 1, 4, 7, 3.25, 0.02, keys, 0.1), wire.units_reply("cam1", 2, 1, 1, 1.0, 0.02, keys[:0],
                                                                                   unchanged=True)]

    def recrc(data: bytes, rnd: random.Random) -> bytes:
        """Fix the frame (body length, CRC) of a mutated message so the body parser is reached."""
        if len(data) < 16:
            return data
        body = data[12:-4]
        head = bytearray(data[:12])
        head[8:12] = struct.pack("<I", len(body))
        head[0:3] = b"DGW"
        head[3] = 1
        return bytes(head) + body + struct.pack("<I", zlib.crc32(bytes(head) + body))

    def case(data: bytes):
        m = wire.decode(data)
        wire.encode(m)                  # an accepted message must encode again (it is whole)
        return True
    return seeds, case, recrc


def _envelope_target(work: Path):
    from depthguard.transport import wire
    from depthguard.transport.auth import Signer, Verifier
    from depthguard.transport.keys import init_authority, issue_node, load_identity

    init_authority(work / "ca")
    issue_node("cam0", work / "ca", work / "cam0")
    ident = load_identity(work / "cam0")
    signer = Signer(ident)
    originals = set()
    seeds = []
    for msg, key in ((wire.init_request("cam0", "a"), "depthguard/init"),
                     (wire.update_request(1, 1, 1.0, 0.02, np.zeros((3, 3)), np.ones(3)), "depthguard/update")):
        env, _ = signer.seal(msg, key)
        seeds.append(env)
        originals.add(env)
    verifier = Verifier(ident.ca_cert, window_s=3600.0)

    def relen(data: bytes, rnd: random.Random) -> bytes:
        """Make the envelope's length fields agree with a mutated size (reach the signature check),
        or change only bytes of the certificate of an intact envelope (reach the X.509 parser)."""
        if rnd.random() < 0.5:
            env = bytearray(rnd.choice(seeds))
            nc = struct.unpack_from("<H", env, 28)[0]
            for _ in range(rnd.randint(1, 3)):
                env[36 + rnd.randrange(nc)] ^= 1 << rnd.randrange(8)
            return bytes(env)
        if len(data) < 36 or data[:3] != b"DGA":
            return data
        nc, ns, nm = struct.unpack_from("<HHI", data, 28)
        rest = len(data) - 36 - nc - ns
        if rest < 0:
            return data
        return data[:28] + struct.pack("<HHI", nc, ns, rest) + data[36:]

    def case(data: bytes):
        verifier._seen.clear()                      # replay protection is not what is fuzzed here
        errors = []
        for k in ("depthguard/init", "depthguard/update"):
            try:
                verifier.open(data, k)
            except ValueError as exc:
                errors.append(exc)
                continue
            if data not in originals:
                raise AssertionError("a mutated envelope verified")
            return True
        raise errors[0]
    return seeds, case, relen


def _settings_target(work: Path):
    from depthguard.distributed.server import FusionServer
    from depthguard.transport import wire

    srv = FusionServer(["cam0"], wire.Settings())
    seeds = [json.dumps(x).encode() for x in (
        {"voxel_size": 0.05}, {"threshold": 0.3, "stale_s": 1.0}, {"offset_const": 0.01, "offset_k": 0.002},
        {"joints": [0.1, -0.2, 0.3]}, {"voxel_size": 0.02, "joints": []})]
    names = ["voxel_size", "threshold", "stale_s", "offset_const", "offset_k", "joints", "epoch", "x", ""]

    def value(rnd: random.Random, depth: int = 0):
        return rnd.choice([lambda: rnd.uniform(-1e3, 1e3), lambda: rnd.choice([0, 1, -1, 10 ** 40, 0.01, 0.1, 60.0]),
                           lambda: rnd.choice([float("nan"), float("inf"), -float("inf"), 1e-300]),
                           lambda: rnd.choice([True, False, None, "", "0.05", "x" * 300]),
                           lambda: [value(rnd, depth + 1) for _ in range(rnd.randint(0, 40 if depth == 0 else 3))]
                           if depth < 2 else 0, lambda: {"a": value(rnd, depth + 1)} if depth < 2 else 1])()

    def structured(data: bytes, rnd: random.Random) -> bytes:
        """A random JSON value, mostly an object of settings names (reach the settings checks)."""
        if rnd.random() < 0.1:
            return json.dumps(value(rnd)).encode()
        return json.dumps({rnd.choice(names): value(rnd) for _ in range(rnd.randint(0, 4))}).encode()

    def case(data: bytes):
        before = srv.settings
        try:
            msg = wire._frame(wire.MsgType.SETTINGS_REQ, data)
        except wire.WireError:
            return False
        rep = wire.decode(srv._on_settings(msg))
        if rep.type == wire.MsgType.ERROR_REP:
            if srv.settings != before:
                raise AssertionError("a rejected settings message changed the settings")
            raise ValueError(rep.text)
        return True
    return seeds, case, structured


def _registry_target(work: Path):
    from depthguard.distributed.registry import Registry

    path = work / "registry.json"
    seeds = [json.dumps({"version": 1, "units": {"camA": 1, "camB": 2}}).encode(),
             json.dumps({"version": 1, "units": {}}).encode()]

    def case(data: bytes):
        path.write_bytes(data)
        try:
            Registry(path)
        finally:
            if path.read_bytes() != data:
                raise AssertionError("loading the registry changed its file")
        return True
    return seeds, case, None


_RIG = """name: fuzz-cell
workspace: {min: [-0.6, -0.6, 0.0], max: [0.6, 0.6, 1.0]}
cameras:
  - id: camA
    width: 64
    height: 48
    fx: 60.0
    fy: 60.0
    cx: 31.5
    cy: 23.5
    range: [0.2, 6.0]
    pose: {look_at: {eye: [1.6, 0.1, 1.4], target: [0.0, 0.0, 0.5]}}
  - id: camB
    width: 64
    height: 48
    fx: 60.0
    fy: 60.0
    cx: 31.5
    cy: 23.5
    range: [0.2, 6.0]
    pose: {translation: [0.0, -1.5, 1.2], quaternion: [0.0, 0.0, 0.0, 1.0]}
objects:
  - {name: table, box: {size: [1.2, 0.8, 0.05]}, pose: {translation: [0, 0, 0.775]}}
"""


def _rig_target(work: Path):
    from depthguard.rig import Rig

    path = work / "rig.yaml"
    seeds = [_RIG.encode()]
    Rig.load(_write(path, seeds[0]))          # the seed itself is valid

    def case(data: bytes):
        Rig.load(_write(path, data))
        return True
    return seeds, case, None


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def _depth_target(work: Path):
    import io

    from PIL import Image

    from depthguard.depth_io import read_depth

    d = np.full((12, 16), 1.5, np.float32)
    d[0, :4] = 0.0
    buf = io.BytesIO()
    np.save(buf, d)
    npy = buf.getvalue()
    buf = io.BytesIO()
    Image.fromarray((d * 1000).astype(np.uint16)).save(buf, format="PNG")
    png = buf.getvalue()
    seeds = [npy, png]

    def case(data: bytes):
        path = work / ("d.png" if (data[:4] == b"\x89PNG" or (data[:1] != b"\x93" and len(data) % 2)) else "d.npy")
        out = read_depth(_write(path, data))
        if out.dtype != np.float32 or out.ndim != 2 or not np.isfinite(out).all() or (out < 0).any():
            raise AssertionError(f"read_depth returned a bad image ({out.dtype}, {out.shape})")
        return True
    return seeds, case, None


def _ros_target(work: Path):
    from depthguard.distributed.fuzz_ros import ros_target
    return ros_target(work)


def _bag_target(work: Path):
    from depthguard.distributed.fuzz_ros import bag_target
    return bag_target(work)


TARGETS: dict[str, Callable] = {"wire": _wire_target, "envelope": _envelope_target, "settings": _settings_target,
                                "registry": _registry_target, "rig": _rig_target, "depth": _depth_target,
                                "ros": _ros_target, "bag": _bag_target}


def run(targets=None, cases: int = 10_000, seed: int = 0, progress: Callable[[str, int], None] | None = None
        ) -> list[FuzzResult]:
    """Fuzz each of ``targets`` (default all) with ``cases`` inputs; one result per target."""
    names = list(TARGETS) if targets is None else list(targets)
    unknown = [n for n in names if n not in TARGETS]
    if unknown:
        raise ValueError(f"unknown fuzz target(s) {', '.join(unknown)}; targets: {', '.join(TARGETS)}")
    if cases < 1:
        raise ValueError(f"--cases must be at least 1 (got {cases})")
    out = []
    for name in names:
        rnd = random.Random(f"{seed}:{name}")
        res = FuzzResult(name)
        with tempfile.TemporaryDirectory(prefix=f"depthguard-fuzz-{name}-") as tmp:
            seeds, case, fix = TARGETS[name](Path(tmp))
            t0 = time.perf_counter()
            for i in range(cases):
                data = mutate(rnd, rnd.choice(seeds), seeds)
                if fix is not None and rnd.random() < 0.5:
                    data = fix(data, rnd)
                res.cases += 1
                try:
                    case(data)
                    res.accepted += 1
                except (ValueError, FileNotFoundError) as exc:
                    if not str(exc).strip():
                        res.crashes += 1
                        if len(res.crash_examples) < 5:
                            res.crash_examples.append((data, f"{type(exc).__name__} without a message"))
                    else:
                        res.rejected += 1
                        k = _kind(exc, tmp)
                        res.errors[k] = res.errors.get(k, 0) + 1
                except Exception:  # noqa: BLE001 - that is what is counted
                    res.crashes += 1
                    if len(res.crash_examples) < 5:
                        res.crash_examples.append((data, traceback.format_exc(limit=6)))
                if progress is not None and (i + 1) % 500 == 0:
                    progress(name, i + 1)
            res.seconds = time.perf_counter() - t0
        out.append(res)
    return out
