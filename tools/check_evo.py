#!/usr/bin/env python3
"""Cross-check `mireg evaluate`'s ATE against evo's `evo_ape`.

Exports the estimate (`/mireg/pose`) and the reference (`/ground_truth/pose` by default) of a
`mireg register` output with `mireg export --format tum`, runs
`evo_ape tum REF EST --align --pose_relation trans_part` (Umeyama SE(3) alignment, no scale,
association within --t_max_diff), and compares evo's APE RMSE with `ate_rmse_m` of
`mireg evaluate --json` (same reference topic, same max dt). Exits 1 if they differ by more than
--tol metres.

Usage (evo: the `evo` group of tools/pyproject.toml):
    bash tools/setup_venv.sh evo
    python3 tools/toolbox.py check-evo /tmp/out.mcap --mireg target/release/mireg
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import zipfile

import mireg_run


def run(cmd, **kw):
    r = subprocess.run(cmd, capture_output=True, text=True, **kw)
    if r.returncode != 0:
        sys.exit(f"command failed ({r.returncode}): {' '.join(cmd)}\n{r.stderr}")
    return r.stdout


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("mcap", help="output of `mireg register`")
    ap.add_argument("--mireg", default=mireg_run.default_binary(), help="mireg binary")
    ap.add_argument(
        "--evo-ape",
        default=os.path.join(os.path.dirname(sys.executable), "evo_ape"),
        help="evo_ape executable [default: next to this Python]",
    )
    ap.add_argument(
        "--evo-rpe",
        default=os.path.join(os.path.dirname(sys.executable), "evo_rpe"),
        help="evo_rpe executable [default: next to this Python]",
    )
    ap.add_argument("--est-topic", default="/mireg/pose")
    ap.add_argument("--gt-topic", default="/ground_truth/pose")
    ap.add_argument("--max-dt", type=float, default=0.01, help="association tolerance [s]")
    ap.add_argument("--tol", type=float, default=1e-6, help="allowed |difference| [m]")
    a = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        est = os.path.join(tmp, "est.tum")
        gt = os.path.join(tmp, "gt.tum")
        res = os.path.join(tmp, "ape.zip")
        run([a.mireg, "export", a.mcap, "--format", "tum", "--topic", a.est_topic, "-o", est])
        run([a.mireg, "export", a.mcap, "--format", "tum", "--topic", a.gt_topic, "-o", gt])
        mireg_json = json.loads(
            run([a.mireg, "evaluate", a.mcap, "--json", "--est-topic", a.est_topic,
                 "--gt-topic", a.gt_topic, "--max-dt", repr(a.max_dt)])
        )
        run([a.evo_ape, "tum", gt, est, "--align", "--pose_relation", "trans_part",
             "--t_max_diff", repr(a.max_dt), "--no_warnings", "--save_results", res])
        with zipfile.ZipFile(res) as z:
            stats = json.loads(z.read("stats.json"))
        # RPE between consecutive frames (no alignment needed: RPE is invariant to it).
        rpe = {}
        for relation in ("trans_part", "angle_deg"):
            out = os.path.join(tmp, f"rpe_{relation}.zip")
            run([a.evo_rpe, "tum", gt, est, "--delta", "1", "--delta_unit", "f",
                 "--pose_relation", relation, "--t_max_diff", repr(a.max_dt),
                 "--no_warnings", "--save_results", out])
            with zipfile.ZipFile(out) as z:
                rpe[relation] = json.loads(z.read("stats.json"))["mean"]
    evo_rmse = stats["rmse"]
    mireg_rmse = mireg_json["ate_rmse_m"]
    diff = abs(evo_rmse - mireg_rmse)
    print(f"frames (mireg)     {mireg_json['frames']}")
    print(f"evo_ape RMSE       {evo_rmse:.12f} m")
    print(f"mireg ate_rmse_m   {mireg_rmse:.12f} m")
    print(f"|difference|       {diff:.3e} m (tolerance {a.tol:g})")
    rpe_t_diff = abs(rpe["trans_part"] - mireg_json["rpe_trans_mean_m"])
    rpe_r_diff = abs(rpe["angle_deg"] - mireg_json["rpe_rot_mean_deg"])
    print(f"evo_rpe mean       {rpe['trans_part']:.12f} m, {rpe['angle_deg']:.12f} deg")
    print(f"mireg rpe mean     {mireg_json['rpe_trans_mean_m']:.12f} m, "
          f"{mireg_json['rpe_rot_mean_deg']:.12f} deg")
    print(f"|difference|       {rpe_t_diff:.3e} m, {rpe_r_diff:.3e} deg (informational)")
    if not diff <= a.tol:
        print("MISMATCH", file=sys.stderr)
        sys.exit(1)
    print("OK")


if __name__ == "__main__":
    main()
