"""A sink added as one module (docs/ARCHITECTURE.md, "How to add a sink").

``csv-scale:FILE`` writes one line per control cycle: the time, the speed scale and the
override. It is called from the fan-out thread (not ``direct``), closed at the end of the
run; registering it is the module's last line; nothing else changes.
"""

from __future__ import annotations

from depthguard.runtime.sink_specs import register_sink


class CsvScale:
    def __init__(self, path):
        self.fh = open(path, "x", encoding="utf-8")     # a run never overwrites a file
        self.fh.write("t,speed_scale,override\n")
        self.describe = f"speed scale to {path}"

    def __call__(self, reaction):
        self.fh.write(f"{reaction.t:.6f},{reaction.speed_scale:.6f},{reaction.override:.6f}\n")

    def close(self):
        self.fh.close()


def open_csv_scale(argument, rig, context):
    if not argument:
        raise ValueError("--sink csv-scale: needs a file, csv-scale:FILE")
    return CsvScale(argument)


register_sink("csv-scale", open_csv_scale)
