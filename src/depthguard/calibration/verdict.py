"""A camera's verdict from its residuals and from where the known scene fits best (R34).

The residual check (:mod:`~depthguard.calibration.residuals`) is coarse: a
D435 at 2 m has a depth noise of about 8 mm, so a camera 1 cm or 0.5 deg off
still shows a median within 1 sigma and few pixels beyond 3 sigma ("good").
The fit (:func:`~depthguard.calibration.refine.refine_pose`) is the fine
measurement: from the right pose it moves less than 0.02 deg and 1 mm on the
built-in cells (docs/CALIBRATION.md, recovery study), so the pose it ends at
says how far off the given one is. :func:`judge` therefore makes the verdict
at least

- ``suspicious`` when the fit lies :data:`SUSPICIOUS_M` (5 mm) or
  :data:`SUSPICIOUS_DEG` (0.25 deg) or more away, or did not converge;
- ``wrong`` when it lies :data:`WRONG_M` (3 cm) or :data:`WRONG_DEG` (1.5 deg)
  or more away;
- ``unknown`` ("cannot judge", never ``good``) when fewer than
  :data:`~depthguard.calibration.residuals.MIN_PIXELS` sampled pixels are
  inliers of the fit, or the fit found the scene nowhere.

Only the directions the scene constrains are measured (the fit keeps the
others as given and reports them).
"""

from __future__ import annotations

import dataclasses

from depthguard.calibration.residuals import MIN_PIXELS, VERDICTS, ResidualStats

__all__ = ["judge", "SUSPICIOUS_M", "SUSPICIOUS_DEG", "WRONG_M", "WRONG_DEG"]

#: the fit lies this far (m) or farther from the given pose: at least suspicious
SUSPICIOUS_M = 0.005
#: ... or turned this much (degrees)
SUSPICIOUS_DEG = 0.25
#: the fit lies this far (m) or farther: wrong
WRONG_M = 0.03
#: ... or turned this much (degrees)
WRONG_DEG = 1.5


def judge(stats: ResidualStats, refinement, offset: tuple[float, float], no_fit: str | None = None) -> ResidualStats:
    """``stats`` with its verdict made at least what the fit says (module docstring).

    refinement : the :class:`~depthguard.calibration.refine.Refinement` from the pose judged;
    offset : ``(degrees, metres)`` from the pose judged to the fit; no_fit : why the fit found
    no scene to fit (its error), None when it ran."""
    if stats.verdict == "unknown":
        return stats
    if no_fit is not None or refinement.inliers < MIN_PIXELS:
        why = no_fit or (f"only {refinement.inliers} sampled pixels fit the known static scene (fewer than "
                         f"{MIN_PIXELS}): the pose cannot be judged")
        return dataclasses.replace(stats, verdict="unknown", reason=why)
    deg, m = offset
    where = f"the known scene fits best {m * 1e3:.1f} mm and {deg:.2f} deg away"
    if not refinement.converged:
        verdict, why = "suspicious", "the fit of the known scene did not converge: the pose is not confirmed"
    elif m >= WRONG_M or deg >= WRONG_DEG:
        verdict, why = "wrong", f"{where} (wrong from {WRONG_M * 1e3:g} mm or {WRONG_DEG:g} deg)"
    elif m >= SUSPICIOUS_M or deg >= SUSPICIOUS_DEG:
        verdict, why = "suspicious", f"{where} (suspicious from {SUSPICIOUS_M * 1e3:g} mm or {SUSPICIOUS_DEG:g} deg)"
    else:
        return stats
    if VERDICTS.index(verdict) > VERDICTS.index(stats.verdict):
        return dataclasses.replace(stats, verdict=verdict, reason=why)
    return stats
