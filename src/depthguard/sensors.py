"""Depth sensor models: intrinsics presets, valid range and noise (R1, issue 2 §6).

A :class:`SensorModel` says what a simulated camera of that kind produces:
image size and field of view (so a rig may name the sensor instead of
writing intrinsics), the valid range, and its noise. The noise itself is
applied by :mod:`depthguard.sources.noise`.

Rated range and return range: ``[min_range, max_range]`` is the *rated*
range, where the sensor's measurements are trusted as surfaces (a camera's
``max_range`` comes from here unless the rig overrides it). Real sensors
still return depth beyond it, less accurately: ``return_range`` is the
farthest depth that returns at all (Kinect v1 about 8 m, D435 10 m, the
generic ToF 12 m; ``None`` = the camera's ``max_range``, as for ``ideal``).
A simulated surface between ``max_range`` and ``return_range`` is measured
with the same noise law; beyond ``return_range`` the pixel is 0. The
product reads such a measurement ``m > max_range`` as "free up to
``max_range``, unknown behind" (R28; :mod:`depthguard.distance.kernels`,
:mod:`depthguard.fusion.depth_grid_kernels`); every other consumer treats
it as invalid, as before.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["SensorModel", "SENSOR_MODELS", "sensor_model", "intrinsics_for", "depth_sigma", "SIGMA_FLOOR",
           "GENERIC_NOISE"]

#: no surface of the CAD is known better than this (m): the noise floor of every camera
SIGMA_FLOOR = 0.002
#: ``(sigma_a, sigma_z2)`` of a camera that names no sensor model (a D435-like stereo camera)
GENERIC_NOISE = (0.001, 0.0025)


@dataclass(frozen=True)
class SensorModel:
    name: str
    resolutions: tuple[tuple[int, int], ...]   # (width, height), first = default
    hfov_deg: float           # nominal field of view (data sheet), degrees
    vfov_deg: float
    min_range: float
    max_range: float          # rated range (trusted as a surface)
    kind: str                 # "structured_light", "stereo", "tof", "ideal"
    # Noise (applied by depthguard.sources.noise):
    sigma_a: float = 0.0      # constant noise term, metres
    sigma_z2: float = 0.0     # noise term growing with z^2: sigma = sigma_a + sigma_z2 * z^2
    disparity_bits: int = 0   # Kinect v1: disparity quantisation (1/8 pixel units)
    baseline: float = 0.0     # stereo / structured light baseline, metres
    edge_dropout: float = 0.0 # probability of a missing return at a depth edge
    flying_pixels: bool = False
    flying_fraction: float = 0.0  # share of the edge pixels between two surfaces that fly (ToF)
    focal_px: tuple[float, ...] = ()   # focal length (pixels, fx = fy) per resolution; () = from hfov
    description: str = ""
    return_range: float | None = None  # farthest depth that returns at all (m); None = max_range

    def __post_init__(self):
        if self.focal_px and len(self.focal_px) != len(self.resolutions):
            raise ValueError(f"sensor {self.name!r}: focal_px needs one value per resolution "
                             f"({len(self.resolutions)}), got {len(self.focal_px)}")
        if any(not (f > 0) for f in self.focal_px):
            raise ValueError(f"sensor {self.name!r}: focal_px must be > 0 (got {self.focal_px})")
        if self.return_range is not None and not (self.return_range >= self.max_range):
            raise ValueError(f"sensor {self.name!r}: return_range must be >= max_range "
                             f"({self.max_range}), got {self.return_range}")

    def returns_to(self, max_range: float | None = None) -> float:
        """The farthest depth (m) that gives a measurement, for a camera whose rated range ends at
        ``max_range`` (default the model's): ``max(return_range, max_range)``, or ``max_range``
        when the model has no return range (``ideal``)."""
        hi = self.max_range if max_range is None else float(max_range)
        return hi if self.return_range is None else max(float(self.return_range), hi)


# The D435's depth modes (Intel RealSense D400 series data sheet: 1280x720, 848x480, 640x480,
# 640x360, 480x270, 424x240, and the high-rate 848x100 and 256x144), the first the default, and
# the focal length of each (px, fx = fy): the 16:9 modes are the 1280x720 image scaled (f = 640 W /
# 1280), 848x100 is a band of 848x480's rows (its f), 640x480 a 4:3 crop (385 px, calibrated units)
_D435_MODES = ((640, 480), (424, 240), (1280, 720), (848, 480), (640, 360), (480, 270), (848, 100), (256, 144))
_D435_FOCAL = (385.0, 212.0, 640.0, 424.0, 320.0, 240.0, 424.0, 128.0)

SENSOR_MODELS: dict[str, SensorModel] = {
    m.name: m
    for m in (
        SensorModel("ideal", ((640, 480), (424, 240), (1280, 720)), 60.0, 45.0, 0.05, 10.0, "ideal",
                    description="noiseless pinhole: exact rendered depth within range"),
        SensorModel("kinect_v1", ((640, 480),), 57.0, 43.0, 0.4, 4.0, "structured_light",
                    sigma_a=0.0, sigma_z2=0.0012, disparity_bits=3, baseline=0.075, edge_dropout=0.3,
                    focal_px=(585.0,), return_range=8.0,
                    description="Microsoft Kinect v1: 640x480, f = 585 px (57.4x44.6 deg; data sheet 57x43), "
                                "0.4-4 m rated (returns to about 8 m), disparity quantised to 1/8 px, "
                                "noise growing with z^2"),
        SensorModel("realsense_d435", _D435_MODES, 87.0, 58.0, 0.2, 6.0, "stereo",
                    sigma_a=0.0005, sigma_z2=0.002, baseline=0.05, edge_dropout=0.2,
                    focal_px=_D435_FOCAL, return_range=10.0,
                    description="Intel RealSense D435 depth: the data sheet's depth modes; f = 640 px at "
                                "1280x720 (90x59 deg; data sheet 87x58) and the same field of view in every "
                                "16:9 mode (f = 640 W / 1280: 424 px at 848x480, 212 px at 424x240), 385 px at "
                                "640x480 (a 4:3 crop, 80x64 deg), 848x100 a band of 848x480's rows; "
                                "0.2-6 m rated (returns to 10 m), noise proportional to z^2"),
        SensorModel("tof", ((320, 240), (640, 480)), 70.0, 55.0, 0.3, 8.0, "tof",
                    sigma_a=0.01, flying_pixels=True, flying_fraction=0.5, edge_dropout=0.05, return_range=12.0,
                    description="generic time-of-flight: 70 deg horizontal (square pixels, 55 deg vertical), "
                                "0.3-8 m rated (returns to 12 m), sigma about 1 cm, flying pixels at depth edges"),
    )
}


def sensor_model(name: str) -> SensorModel:
    """The sensor model called ``name``; ``ValueError`` listing the known ones otherwise."""
    try:
        return SENSOR_MODELS[name]
    except KeyError:
        raise ValueError(f"unknown sensor model {name!r}; known: {', '.join(sorted(SENSOR_MODELS))}") from None


def intrinsics_for(name: str, width: int | None = None, height: int | None = None) -> dict:
    """``width, height, fx, fy, cx, cy, min_range, max_range`` of a sensor preset.

    Square pixels, as on real depth sensors: ``fx = fy`` = the preset's focal
    length for that mode (typical calibrated values), or ``(W/2) / tan(hfov/2)``
    for presets without one; the vertical field of view follows from it. The
    principal point is the image centre ``((W-1)/2, (H-1)/2)``.
    """
    m = sensor_model(name)
    if width is None and height is None:
        width, height = m.resolutions[0]
    elif width is None or height is None:
        raise ValueError(f"sensor {name!r}: give both width and height or neither")
    if (width, height) not in m.resolutions and m.kind != "ideal":
        res = ", ".join(f"{w}x{h}" for w, h in m.resolutions)
        raise ValueError(f"sensor {name!r} has no {width}x{height} mode; modes: {res} - or give the camera's "
                         f"intrinsics explicitly (width, height, fx, fy, cx, cy in pixels, with the sensor kept "
                         f"for its range and noise)")
    if m.focal_px and (width, height) in m.resolutions:
        f = float(m.focal_px[m.resolutions.index((width, height))])
    else:
        f = (width / 2) / math.tan(math.radians(m.hfov_deg) / 2)
    return dict(width=width, height=height, fx=f, fy=f, cx=(width - 1) / 2, cy=(height - 1) / 2,
                min_range=m.min_range, max_range=m.max_range)


def depth_sigma(cam, z):
    """Standard deviation (m) of camera ``cam``'s depth at ``z`` (m), same shape as ``z`` (R1, R34):
    ``sigma_a + sigma_z2 z^2`` of its sensor model, with the disparity quantisation step
    ``z^2 / (f b 2^bits)`` added as a uniform error (``step / sqrt(12)``), never below
    :data:`SIGMA_FLOOR`; :data:`GENERIC_NOISE` for a camera without a sensor model."""
    import numpy as np

    z = np.asarray(z, dtype=np.float64)
    model = SENSOR_MODELS.get(getattr(cam, "sensor", None) or "")
    if model is None:
        a, b = GENERIC_NOISE
        s = a + b * z * z
    else:
        s = model.sigma_a + model.sigma_z2 * z * z
        if model.disparity_bits and model.baseline > 0:
            step = z * z / (float(cam.fx) * model.baseline * 2.0 ** model.disparity_bits)
            s = np.sqrt(s * s + step * step / 12.0)
    return np.maximum(s, SIGMA_FLOOR)
