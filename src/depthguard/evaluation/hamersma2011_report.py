"""The Markdown report of the Hamersma 2011 reproduction (``report.md``, R21–R24).

:func:`report_markdown` turns the results dict of
:func:`depthguard.evaluation.hamersma2011.run` (what it writes as
``results.json``) into the tables beside the paper's figures:
accuracy per setup (tables 1–2), motion verdicts (table 4), the calibration
study, the placement check (fig. 4).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from depthguard.evaluation.accuracy import Confusion
from depthguard.evaluation.hamersma2011_paper import AXIS_LABEL, GOALS, MARGIN, PAPER, PRODUCT, SHELL_TOLERANCE

__all__ = ["jsonable", "report_markdown"]


def jsonable(x):
    """``x`` with numpy scalars as Python numbers and non-finite floats as None (JSON)."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, (np.floating, float)):
        return None if not math.isfinite(float(x)) else float(x)
    if isinstance(x, np.integer):
        return int(x)
    return x


def _pct(x):
    return "n/a" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{100 * x:.1f}"


def _conf(d) -> Confusion:
    return Confusion(d["correct_free"], d["free_as_object"], d["correct_object"], d["object_as_free"])


def _fmt_u(u):
    return "–" if u is None or not math.isfinite(u) else f"{u:.2f}"


def report_markdown(res: dict) -> str:
    L = ["# Hamersma 2011 on `c-arm-room`", ""]
    L.append(f"Setups: {', '.join(res['setups'])}; seed {res['seed']}; voxel sizes "
             f"{', '.join(f'{v * 100:.0f} cm' for v in res['voxels'])}; run time {res.get('seconds', 0):.0f} s."
             + (" QUICK run (two setups, no approach series): not figures to quote." if res["quick"] else ""))
    L.append("")
    L.append("Braking distances S (top speed, 0.2 s reaction, stop in 1 s): "
             + ", ".join(f"{AXIS_LABEL[a]} {math.degrees(v):.1f}°" if a != "longitudinal"
                         else f"{AXIS_LABEL[a]} {v * 100:.1f} cm" for a, v in res["braking"].items())
             + "; M = 2 S, L = 5 S.")
    L.append("")
    for label, rr in res["rigs"].items():
        L.append(f"# Rig `{label}` ({rr['cameras']} cameras)")
        L.append("")
        for vs in res["voxels"]:
            acc = rr["accuracy"][vs]
            variants = [k for k in (PRODUCT, "single", "paper", "full", "bound", "noiseless") if k in acc]
            prod = res["product"]
            pm_cm = 100 * prod["margin_m"]
            L.append(f"## Accuracy at {vs * 100:.0f} cm (tables 1-2), rig `{label}`")
            L.append("")
            L.append("free % = correct free / truly free; object % = correct object / truly occupied; the C-arm's "
                     f"own (freed) voxels are left out. **`shell` is the product**: {prod['frames']} consecutive ToF "
                     "frames per camera of the still scene fused per pixel (the median where they agree within "
                     f"{prod['agree_k']:.1f} sigma, else the nearest: fusion/temporal.py; fused noise "
                     f"{100 * prod['fused_sigma_m']:.2f} cm), centre pixel, centre depth + {pm_cm:.2f} cm (2 sigma of "
                     "the fused depth), and the room's known shell (floor, walls, ceiling) as each camera's "
                     f"background: a measurement within {100 * prod['tolerance_m']:.2f} cm (margin + 3 sigma) of the "
                     "shell is the shell, not a surface in the voxel. `single`: the same from one frame, margin "
                     f"{100 * MARGIN:.0f} cm, tolerance {100 * SHELL_TOLERANCE:.0f} cm. `paper`: the paper's own method "
                     f"(one frame, margin {100 * MARGIN:.0f} cm, no background; the column to compare with the paper); "
                     "`full`: one frame, every pixel of the voxel's projection, no background; `bound`: noiseless, "
                     "every pixel (what the resolution allows); `noiseless`: the product's map on noiseless images "
                     f"(what its rule and {pm_cm:.2f} cm margin allow against a centre-based truth). n1..n4, `unseen` "
                     "(truly free voxels in no camera's view) and `hidden` (truly free voxels no camera sees free "
                     "even in noiseless images) for `shell`.")
            L.append("")
            head = "| setup | " + " | ".join(f"free % {k} | object % {k}" for k in variants) + \
                   " | n1 | n2 | n3 | n4 | unseen | hidden | paper (2011) free / object |"
            L.append(head)
            L.append("|" + "---|" * (2 * len(variants) + 8))
            tot = {k: Confusion(0, 0, 0, 0) for k in variants}
            unseen_tot = 0
            for i, st in enumerate(res["setups"]):
                cells = []
                for k in variants:
                    c = _conf(acc[k][st])
                    tot[k] = tot[k] + c
                    cells += [_pct(c.free_accuracy), _pct(c.object_accuracy)]
                p = _conf(acc[PRODUCT][st])
                un = acc["unseen_free"][st]
                unseen_tot += un
                pp = PAPER["table2"].get(i + 1)
                L.append(f"| {st} | " + " | ".join(cells) + f" | {p.correct_free} | {p.free_as_object} | "
                         f"{p.correct_object} | {p.object_as_free} | {un} | {acc['hidden_free'][st]} | "
                         f"{'' if pp is None else f'{pp[0]} / {pp[1]}'} |")
            cells = []
            for k in variants:
                cells += [f"**{_pct(tot[k].free_accuracy)}**", f"**{_pct(tot[k].object_accuracy)}**"]
            tp = tot[PRODUCT]
            L.append("| **all** | " + " | ".join(cells) + f" | {tp.correct_free} | {tp.free_as_object} | "
                     f"{tp.correct_object} | {tp.object_as_free} | {unseen_tot} | {sum(acc['hidden_free'].values())} | "
                     f"{PAPER['free']} / {PAPER['object']} |")
            L.append("")
            agg = {}
            for st, per in rr["objects"][vs].items():
                for name, d in per.items():
                    a = agg.setdefault(name, [0, 0, d["smallest_extent_m"]])
                    a[0] += d["voxels"]; a[1] += d["seen_as_free"]; a[2] = min(a[2], d["smallest_extent_m"])
            worst = [kv for kv in sorted(agg.items(), key=lambda kv: -kv[1][1]) if kv[1][1]][:8]
            if worst:
                L.append("Objects seen as free (`shell`, all setups): " + "; ".join(
                    f"{k} {v[1]}/{v[0]} voxels (smallest extent {v[2] * 100:.0f} cm)" for k, v in worst) + ".")
                L.append("")
            # goals, judged on the product
            best_free = tp.free_accuracy
            best_obj = tp.object_accuracy
            tpp = tot["paper"]
            L.append(f"Goals at {vs * 100:.0f} cm (product `shell`): free >= {GOALS['free']} %: "
                     f"{'met' if 100 * best_free >= GOALS['free'] else 'NOT met'} ({100 * best_free:.2f} %); "
                     f"objects >= {GOALS['object']} %: {'met' if 100 * best_obj >= GOALS['object'] else 'NOT met'} "
                     f"({_pct(best_obj)} %). The paper's method (`paper`): free {_pct(tpp.free_accuracy)} %, "
                     f"objects {_pct(tpp.object_accuracy)} %.")
            n_free = tp.n_free
            hidden_tot = sum(acc["hidden_free"].values())
            if n_free and 100 * best_free < GOALS["free"]:
                ceiling = 100.0 * (1 - hidden_tot / n_free)
                L.append(f"Ceiling on free space: of the truly free voxels, {unseen_tot} ({100 * unseen_tot / n_free:.2f} %) "
                         f"are in no camera's view and {hidden_tot - unseen_tot} more "
                         f"({100 * (hidden_tot - unseen_tot) / n_free:.2f} %) are in view but in the shadow of something "
                         "(table, people, C-arm, furniture) for every camera: even noiseless images show none of them "
                         f"free, so free space is capped at {ceiling:.2f} % with this rig — "
                         + (f"the goal of {GOALS['free']} % is impossible by {GOALS['free'] - ceiling:.2f} points. "
                            if ceiling < GOALS["free"] else
                            f"above the goal of {GOALS['free']} %: what the cameras see is not what limits free space. ")
                         + f"The rest of the gap ({ceiling - 100 * tp.free_accuracy:.2f} points for `shell`, "
                         f"{ceiling - 100 * tpp.free_accuracy:.2f} for `paper`) is noise against the margin and "
                         "voxels whose centre lies within about a margin of a surface (objects, the C-arm, and — "
                         "for `paper` — the floor, walls and ceiling).")
                for key, k, mg in (("near_surface_missed", PRODUCT, pm_cm), ("near_surface_missed_paper", "paper",
                                                                               100 * MARGIN)):
                    near_d = acc.get(key)
                    tk = tot[k]
                    if near_d is not None and tk.free_as_object:
                        near_tot = sum(near_d.values())
                        L.append(f"Of the {tk.free_as_object} free voxels seen as object (`{k}`), {near_tot} "
                                 f"({100 * near_tot / tk.free_as_object:.1f} %; {100 * near_tot / n_free:.2f} % of the "
                                 f"free space) have their centre within half a voxel + the {mg:.2f} cm margin "
                                 "of a surface (obstacles, C-arm, shell): there the surface lies at most that far behind "
                                 "the centre, so the sensor noise against the margin decides; leaving them "
                                 f"out, free space is {100 * tk.correct_free / max(1, n_free - near_tot):.2f} %.")
            if "noiseless" in tot and 100 * best_free < GOALS["free"]:
                nl = 100 * tot["noiseless"].free_accuracy
                L.append(f"The product's map on **noiseless** images (same rule, same {pm_cm:.2f} cm margin, same "
                         f"background) frees {nl:.2f} % — "
                         + (f"so at {vs * 100:.0f} cm the goal of {GOALS['free']} % is out of reach of this rule with a "
                            f"2 sigma margin by {GOALS['free'] - nl:.2f} points before any noise: voxels whose centre "
                            "lies within the margin in front of a surface (or that hold a surface in front of their "
                            "free centre) are called free by the truth and can never be freed by a camera. "
                            if nl < GOALS["free"] else
                            f"above the goal: at {vs * 100:.0f} cm the sensor noise, not the rule, is what keeps "
                            f"free space {nl - 100 * best_free:.2f} points lower. ")
                         + "A smaller margin needs less noise per view (see the margin trade-off below).")
            if "bound" in tot and 100 * tot["bound"].object_accuracy < GOALS["object"]:
                b = tot["bound"].object_accuracy
                L.append(f"Noiseless cameras reading every pixel of each voxel reach {_pct(b)} % of the objects: "
                         f"the object goal is impossible with these cameras by {GOALS['object'] - 100 * b:.1f} points.")
            sw = rr.get("margin_sweep", {}).get(vs)
            if sw:
                L.append("")
                L.append(f"Margin trade-off at {vs * 100:.0f} cm of one frame per camera (`single`: the same "
                         f"frames and background; {MARGIN * 100:.0f} cm = 2 sigma of the ToF noise of one frame; the "
                         f"product fuses {prod['frames']} frames instead and keeps 2 sigma of the fused depth):")
                L.append("")
                L.append("| margin (cm) | free % | object % | free seen as object | object seen as free | "
                         "verdicts of the base motions (u = unsafe) |")
                L.append("|---|---|---|---|---|---|")
                for mg, d in sorted(sw.items(), key=lambda x: float(x[0])):
                    c = _conf(d)
                    vd = d.get("verdicts") or {}
                    vtxt = ", ".join(f"{k} {vd.get(k, 0)}" for k in ("s", "ts", "tts", "u")) if vd else "–"
                    L.append(f"| {float(mg) * 100:.1f} | {100 * c.free_accuracy:.3f} | {100 * c.object_accuracy:.2f} | "
                             f"{c.free_as_object} | {c.object_as_free} | {vtxt} |")
                ok = [float(mg) for mg, d in sw.items() if 100 * _conf(d).free_accuracy >= GOALS["free"]]
                L.append("")
                L.append((f"Free >= {GOALS['free']} % needs a margin of at most {max(ok) * 100:.1f} cm here"
                          if ok else f"No margin down to {min(float(m) for m in sw) * 100:.1f} cm reaches free >= "
                                     f"{GOALS['free']} % here")
                         + ": a smaller margin frees the voxels whose centre lies just in front of a surface, and "
                           "lets the noise free more of the objects' boundary voxels (object seen as free). With one "
                           "frame a smaller margin costs safety; the product lowers the noise instead (several "
                           "frames fused) and keeps 2 sigma (the verdict column counts the base motions only, "
                           "without the approach series below).")
            L.append("")
        for vs in res["voxels"]:
            rows = rr["verdicts"][vs]
            L.append(f"## Motion verdicts at {vs * 100:.0f} cm (table 4), rig `{label}`")
            L.append("")
            L.append("Reconstruction (product `shell`; `paper` = the paper's method on the same frames) vs "
                     "ground truth (same sweep, same exclusion of the C-arm's own volume); "
                     "s = same, ts = 1-2 levels more severe, tts = stop where the truth is free, u = less severe "
                     "(unsafe). u = first contact in multiples of S. `k x M`: the C-arm first advanced by k-1 S "
                     "along M, re-rendered and re-reconstructed.")
            L.append("")
            L.append("| setup | motion | reconstruction | truth | verdict | u recon | u truth | paper recon | "
                     "paper verdict |")
            L.append("|---|---|---|---|---|---|---|---|---|")
            for r in rows:
                L.append(f"| {r['setup']} | {r['motion']} | {r['reconstruction']} | {r['truth']} | {r['verdict']} | "
                         f"{_fmt_u(r['u_recon'])} | {_fmt_u(r['u_truth'])} | {r.get('paper_reconstruction', '')} | "
                         f"{r.get('paper_verdict', '')} |")
            cnt = {k: sum(r["verdict"] == k for r in rows) for k in ("s", "ts", "tts", "u")}
            cp = {k: sum(r.get("paper_verdict") == k for r in rows) for k in ("s", "ts", "tts", "u")}
            L.append("")
            L.append(f"{len(rows)} motions, `shell` (product): s {cnt['s']}, ts {cnt['ts']}, tts {cnt['tts']}, "
                     f"**u {cnt['u']}**; `paper` method: s {cp['s']}, ts {cp['ts']}, tts {cp['tts']}, u {cp['u']} "
                     f"(the paper (2011): 27 s, 6 ts/tts, 2 u of 35; goal: no u).")
            L.append("")
        if rr["calibration"]:
            L.append(f"## Calibration study (paper §6.1.2), rig `{label}`")
            L.append("")
            L.append("The map's camera model disturbed (each rotation angle uniform in ±1°, each translation "
                     "component in ±1 cm), images from the true cameras; all setups pooled; `shell` (product, its "
                     "background rendered with the disturbed cameras) and `paper`. "
                     "1° is about 4 pixels of these 320x240 70° cameras (the paper: about 1 pixel).")
            L.append("")
            L.append("| voxel | disturbance | free % shell | object % shell | free % paper | object % paper |")
            L.append("|---|---|---|---|---|---|")
            for vs, cal in rr["calibration"].items():
                for lab in ("none", "rotation ±1°", "rotation ±1°, calibrated", "translation ±1 cm", "both"):
                    if lab not in cal:
                        continue
                    d, dp = cal[lab][PRODUCT], cal[lab]["paper"]
                    L.append(f"| {float(vs) * 100:.0f} cm | {lab} | {_pct(d['free_accuracy'])} | "
                             f"{_pct(d['object_accuracy'])} | {_pct(dp['free_accuracy'])} | "
                             f"{_pct(dp['object_accuracy'])} |")
            L.append("")
            ce = rr.get("calibration_errors")
            if ce:
                L.append(f"`rotation ±1°, calibrated` (R34): the disturbed cameras refined with `depthguard calibrate`'s "
                         f"solver against the room's static CAD from the first setup's still frames (people and the "
                         f"C-arm in view), then the same reconstruction. Pose errors left over the {ce['cameras']} "
                         f"cameras: median {ce['after_deg_median']:.4f}° / {ce['after_mm_median']:.2f} mm, worst "
                         f"{ce['after_deg_max']:.4f}° / {ce['after_mm_max']:.2f} mm (disturbed: up to "
                         f"{ce['before_deg_max']:.2f}°).")
                L.append("")
    pl = res.get("placement")
    if pl:
        L.append("# Sensor placement (R23, fig. 4)")
        L.append("")
        L.append(f"Empty room (shell only: {', '.join(pl['shell'])}), {pl['voxel'] * 100:.0f} cm voxels. Criterion: "
                 ">= 3 cameras pairwise >= 100° apart in the horizontal plane. Candidates for the greedy improver: "
                 f"{pl['candidates']} positions every 0.5 m on wall rings "
                 + ", ".join(f"at {h} m looking at {list(t)}" for h, t in pl["rings"])
                 + " and a ceiling grid.")
        L.append("")
        L.append("The improver aims at 99.5 % of what all candidates together reach (at most 40 cameras).")
        L.append("")
        L.append("| region | the cell's 21 cameras | all candidates | improver: cameras | improver: share |")
        L.append("|---|---|---|---|---|")
        for reg, d in pl["regions"].items():
            L.append(f"| {reg} {np.round(d['lo'], 2).tolist()}..{np.round(d['hi'], 2).tolist()} | {_pct(d['rig_share'])} % | "
                     f"{_pct(d['candidates_all_share'])} % | {d['improver_cameras']} | {_pct(d['improver_share'])} % |")
        L.append("")
        box = pl["regions"]["box"]
        L.append("Why the whole box cannot pass: the cameras that see a voxel next to a wall all sit on the other "
                 "side of it (a camera on the near wall has it behind or beside itself), i.e. within a half plane "
                 "of azimuths; three azimuths pairwise >= 100° apart span more than 180°. Share of the box passing "
                 "per height (cell rig): " + ", ".join(f"{v:.2f}" for v in box["rig_share_by_z"]) + ".")
        L.append("")
        it = pl["regions"]["interior"]
        L.append("Fig. 4 (interior): share vs number of the cell's cameras, best first: "
                 + ", ".join(f"{i + 1}: {_pct(v)}" for i, v in enumerate(it["rig_curve"]))
                 + f". Improver ({it['improver_cameras']} cameras, paper: 21): "
                 + ", ".join(f"{i + 1}: {_pct(v)}" for i, v in enumerate(it["improver_curve"])) + ".")
        L.append("")
        L.append("Improver positions (interior): " + "; ".join(str(p) for p in it["improver_positions"]) + ".")
        L.append("")
    L.append("Pictures: " + ", ".join(Path(p).name for p in res["pictures"])
             + (", fig4_placement.png" if pl else "") + ".")
    L.append("")
    return "\n".join(L)
