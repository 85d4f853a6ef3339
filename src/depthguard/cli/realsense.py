"""``depthguard rig from-realsense``: a rig's camera blocks from RealSense devices or recordings (R1, R2).

For each device (``--serial``, repeatable; default every connected device) or
SDK recording (``--file``, repeatable), the depth stream's size and intrinsics
as the SDK reports them (the mode nearest ``--width`` x ``--height`` @ ``--fps``),
the sensor preset of the product line and its rated range. The camera's pose in
the world cannot be read from a device: each block has ``pose: null`` and a
comment, so that a rig using it does not load until the pose is written (by
hand, or by the calibration command). ``--out`` is never overwritten.

The ``rig`` command group (``depthguard.cli.app.rig_app``) is shared with ``rig from-bag``.
"""

from __future__ import annotations

import datetime
from pathlib import Path
from typing import List

import typer

from depthguard.cli.app import rig_app

__all__ = ["camera_blocks", "blocks_yaml"]



def _device_block(rs, device, where: str, width: int, height: int, fps: float, camera_id: str) -> dict:
    from depthguard.sensors import sensor_model
    from depthguard.sources.realsense import describe_streams
    from depthguard.sources.realsense_device import depth_profiles, intrinsics_of

    try:
        sensor = device.first_depth_sensor()
    except RuntimeError:
        raise ValueError(f"{where}: the device holds no depth stream; it holds {describe_streams(rs, device)}") \
            from None
    profiles = depth_profiles(rs, sensor)
    if not profiles:
        raise ValueError(f"{where}: the device has no z16 depth stream")

    def key(p):
        v = p.as_video_stream_profile()
        return (abs(v.width() * v.height() - width * height), abs(v.width() - width), abs(p.fps() - fps))
    intr = intrinsics_of(min(profiles, key=key))
    info = {k: (device.get_info(getattr(rs.camera_info, k)) if device.supports(getattr(rs.camera_info, k)) else "")
            for k in ("name", "serial_number", "firmware_version")}
    product = info["name"]
    preset = "realsense_d435" if "D4" in product.upper() else None
    if preset is not None:
        m = sensor_model(preset)
        rng = [m.min_range, m.max_range]
    else:
        rng = [0.2, 6.0]
    block = {"id": camera_id, "width": intr["width"], "height": intr["height"], "fx": round(intr["fx"], 6),
             "fy": round(intr["fy"], 6), "cx": round(intr["cx"], 6), "cy": round(intr["cy"], 6), "range": rng,
             "pose": None}
    if preset is not None:
        block = {"id": camera_id, "sensor": preset, **{k: v for k, v in block.items() if k != "id"}}
    if any(abs(c) > 1e-9 for c in intr["coeffs"]):
        raise ValueError(f"{where}: the depth stream has lens distortion {intr['model']} {intr['coeffs']}; "
                         "the monitor needs a rectified depth stream")
    comment = (f"{product or 'RealSense device'} serial {info['serial_number'] or '?'}"
               + (f", firmware {info['firmware_version']}" if info["firmware_version"] else "")
               + f", depth {intr['width']}x{intr['height']} @ {intr['fps']} Hz ({where})"
               + ("" if preset else "; no sensor preset for this product: range is a guess, check it"))
    return {"block": block, "comment": comment, "serial": info["serial_number"], "fps": intr["fps"]}


def camera_blocks(serials: list[str], files: list[Path], width: int = 848, height: int = 480,
                  fps: float = 30.0, ids: list[str] | None = None) -> list[dict]:
    """One ``{"block": camera dict, "comment": str, ...}`` per device or recording (module docstring)."""
    from depthguard.sources.realsense_device import import_sdk

    rs = import_sdk()
    ctx = rs.context()
    found = []
    if files:
        for f in files:
            if not f.is_file():
                raise FileNotFoundError(f"--file {f}: recording not found")
            try:
                found.append((ctx.load_device(str(f)), f"recording {f.name}"))
            except RuntimeError as exc:
                raise ValueError(f"--file {f}: the SDK cannot read it as a recording ({exc})") from None
    else:
        present = {d.get_info(rs.camera_info.serial_number): d for d in ctx.query_devices()}
        missing = [s for s in serials if s not in present]
        if missing or not present:
            raise ValueError(f"device(s) {', '.join(missing) or '(any)'} not connected; connected: "
                             f"{', '.join(sorted(present)) or 'none'}")
        found = [(present[s], f"device {s}") for s in (serials or sorted(present))]
    if ids is not None and len(ids) != len(found):
        raise ValueError(f"--id given {len(ids)} times for {len(found)} camera(s)")
    out = []
    for i, (device, where) in enumerate(found):
        serial = device.get_info(rs.camera_info.serial_number) if device.supports(rs.camera_info.serial_number) else ""
        cid = ids[i] if ids else (f"rs_{serial}" if serial else f"rs{i}")
        out.append(_device_block(rs, device, where, width, height, fps, cid))
    return out


def blocks_yaml(blocks: list[dict], command: str) -> str:
    """The YAML text of the camera blocks, each commented, the pose left ``null`` with a TODO."""
    import yaml

    from depthguard.config import check_camera_id

    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = [f"# Camera blocks written by `{command}` on {stamp}.",
             "# Copy them under `cameras:` of your rig file (docs/REALSENSE.md).",
             "# Each camera's POSE IS NOT KNOWN from the device: replace every `pose: null` by the pose of the",
             "# camera's optical frame (z forward) in the world - translation + quaternion, matrix or look_at -",
             "# or let the calibration command write it. A rig with `pose: null` does not load.",
             "cameras:"]
    for b in blocks:
        check_camera_id(b["block"]["id"])
        text = yaml.safe_dump([b["block"]], sort_keys=False, default_flow_style=None).rstrip("\n")
        text = text.replace("pose: null", "pose: null   # TODO: the camera's pose in the world (see above)")
        lines.append(f"# {b['comment']}")
        lines.extend(text.splitlines())
    return "\n".join(lines) + "\n"


@rig_app.command("from-realsense")
def from_realsense(
    out: Path = typer.Option(..., "--out", "-o", help="The YAML file to write (must not exist)."),
    serial: List[str] = typer.Option([], "--serial", help="A connected device's serial number (repeatable; default every connected device)."),
    file: List[Path] = typer.Option([], "--file", help="An SDK recording (.db3 or .bag) instead of a device (repeatable)."),
    camera_id: List[str] = typer.Option([], "--id", help="The camera id of each block, in order (default rs_<serial>)."),
    width: int = typer.Option(848, "--width", help="Depth image width wanted (px); the nearest mode is written."),
    height: int = typer.Option(480, "--height", help="Depth image height wanted (px)."),
    fps: float = typer.Option(30.0, "--fps", help="Frame rate wanted (Hz)."),
) -> None:
    """Write the camera block(s) of RealSense devices or recordings: intrinsics, range, sensor preset.

    The pose of each camera is left for you (or the calibration command): it is
    written as ``pose: null`` with a comment, so that the rig does not load
    until the pose is there.
    """
    if serial and file:
        raise typer.BadParameter("give --serial or --file, not both", param_hint="--serial/--file")
    if width <= 0 or height <= 0 or not fps > 0:
        raise typer.BadParameter("--width, --height and --fps must be > 0")
    if out.exists():
        raise ValueError(f"--out {out}: exists already (nothing is overwritten); choose a new file")
    if not out.parent.is_dir():
        raise ValueError(f"--out {out}: the folder {out.parent} does not exist")
    blocks = camera_blocks(list(serial), list(file), width, height, fps, list(camera_id) or None)
    cmd = "depthguard rig from-realsense " + " ".join([*(f"--serial {s}" for s in serial),
                                                        *(f"--file {f}" for f in file)])
    text = blocks_yaml(blocks, cmd.strip())
    with open(out, "x", encoding="utf-8") as fh:
        fh.write(text)
    for b in blocks:
        c = b["block"]
        typer.echo(f"{c['id']}: {c['width']}x{c['height']} fx {c['fx']:.2f} fy {c['fy']:.2f} "
                   f"cx {c['cx']:.2f} cy {c['cy']:.2f} @ {b['fps']} Hz - {b['comment']}")
    typer.echo(f"wrote {out}: set each camera's pose (pose: null) before using it")
