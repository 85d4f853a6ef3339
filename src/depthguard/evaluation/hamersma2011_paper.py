"""Hamersma 2011's figures and the constants of its reproduction (R21–R24).

``PAPER``: the paper's accuracy (table 2, per setup and pooled, %), unsafe
verdicts and motions (table 4); ``GOALS``: what the product aims at. The
other constants are the study's choices, explained in
:mod:`depthguard.evaluation.hamersma2011`: margins in metres, times in seconds.
"""

from __future__ import annotations

__all__ = ["PAPER", "GOALS", "REACTION_TIME", "MARGIN", "MARGIN_SWEEP", "TOF_SIGMA", "SHELL_TOLERANCE",
           "PRODUCT", "FRAME_PERIOD", "AXES", "AXIS_LABEL"]

PAPER = {"free": 98.9, "object": 91.1, "unsafe": 2, "motions": 35,
         "table2": {1: (99.1, 89.1), 2: (98.7, 94.0), 3: (98.7, 93.0), 4: (98.6, 89.0),
                    5: (99.2, 90.2), 6: (99.0, 87.3)}}
GOALS = {"free": 99.5, "object": 97.0, "unsafe": 0}
REACTION_TIME = 0.2
MARGIN = 0.02
MARGIN_SWEEP = (0.005, 0.01, 0.015, 0.02)   # the product's margin trade-off, reported beside it
TOF_SIGMA = 0.01                       # the cell's ToF sensor model: sigma about 1 cm
SHELL_TOLERANCE = MARGIN + 3 * TOF_SIGMA   # a measurement this close to the known shell is the shell
PRODUCT = "shell"                      # the reconstruction reported as the product's
FRAME_PERIOD = 1.0 / 30.0              # s between a camera's consecutive frames (30 Hz ToF)
AXES = ("larm", "propeller", "carc", "longitudinal")
AXIS_LABEL = {"larm": "Larm", "propeller": "Prop", "carc": "Carc", "longitudinal": "Long"}
