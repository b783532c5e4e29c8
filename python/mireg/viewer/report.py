"""One-page PNG report of a mireg output MCAP (matplotlib, no display needed).

Panels:
  1. trajectory top view: estimate (``/mireg/pose``) vs reference (``/ground_truth/pose``, if the
     log has it, aligned to the estimate as ``mireg evaluate --odometry`` aligns it), projected on the plane orthogonal to "up" (−y for ``*optical_frame`` clouds, whose
     world is the first sensor frame: x right / z forward; +z otherwise); failed frames as red x;
  2. per-frame RANSAC inliers and correspondences (``/mireg/stats``; none on frames tracked on the
     local map, which skip global registration), failed frames shaded red;
  3. per-frame relative pose error (RPE) translation [cm] and
  4. rotation [deg] of the estimate against the reference, computed here as
     ``E_k = (ref_{k−1}⁻¹ ref_k)⁻¹ (est_{k−1}⁻¹ est_k)``: translation error ‖t(E_k)‖, rotation error
     the angle of R(E_k). (The reference of the ICL fixture is Open3D's estimate, not ground truth.)

The title carries the file, the mireg version and seed from the ``mireg`` metadata record and the
summary numbers (failures, mean / median / max RPE), which are also printed.

Usage (``pip install "./python[viewer]"``):
    python -m mireg.viewer.report /tmp/out.mcap -o docs/report.png
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ..run import read_run
from .timeline import up_vector


def rpe(est: list[np.ndarray], ref: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame RPE (translation [m], rotation [deg]); entry k compares the step k−1 → k, entry 0
    is NaN. Frames with a missing pose on either side give NaN too."""
    n = len(est)
    trans, rot = np.full(n, np.nan), np.full(n, np.nan)
    for k in range(1, n):
        if any(m is None for m in (est[k - 1], est[k], ref[k - 1], ref[k])):
            continue
        ref_step = np.linalg.inv(ref[k - 1]) @ ref[k]
        est_step = np.linalg.inv(est[k - 1]) @ est[k]
        err = np.linalg.inv(ref_step) @ est_step
        trans[k] = np.linalg.norm(err[:3, 3])
        cos = np.clip((np.trace(err[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
        rot[k] = np.degrees(np.arccos(cos))
    return trans, rot


def horizontal_axes(up: np.ndarray) -> tuple[int, int, str, str]:
    """The two world axes spanning the ground plane and their labels."""
    if abs(up[1]) > 0.5:  # optical frame: x right, z forward
        return 0, 2, "x (right) [m]", "z (forward) [m]"
    return 0, 1, "x [m]", "y [m]"


def make_report(mcap: Path, out: Path, dpi: int = 110) -> dict:
    """Write the PNG; return the summary numbers."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    run = read_run(mcap, load_clouds=False)  # poses, stats, and the first cloud's frame_id
    frames = run.frames
    idx = np.array([f.index for f in frames])
    est = [f.estimate for f in frames]
    ref = [f.reference for f in frames]
    stats = [f.stats or {} for f in frames]
    failed = np.array([s.get("success", True) is False for s in stats], dtype=bool)
    up = up_vector(frames[0].frame_id if frames else "")
    ax_a, ax_b, label_a, label_b = horizontal_axes(up)

    fig, axes = plt.subplots(2, 2, figsize=(13, 9))
    ax_traj, ax_inl, ax_t, ax_r = axes.ravel()

    est_pos = np.array([m[:3, 3] if m is not None else [np.nan] * 3 for m in est])
    ax_traj.plot(est_pos[:, ax_a], est_pos[:, ax_b], "-", color="tab:blue", lw=1.5,
                 label="estimate (/mireg/pose)")
    if any(m is not None for m in ref):
        # laid onto the estimate as `mireg evaluate --odometry` aligns them
        align = run.estimate_from_reference("estimate")
        ref_pos = np.array([(align @ m)[:3, 3] if m is not None else [np.nan] * 3 for m in ref])
        ax_traj.plot(ref_pos[:, ax_a], ref_pos[:, ax_b], "--", color="tab:green", lw=1.5,
                     label="reference (/ground_truth/pose)")
    if len(est_pos):
        ax_traj.plot(est_pos[0, ax_a], est_pos[0, ax_b], "ko", ms=6, label="first frame")
    if failed.any():
        ax_traj.plot(est_pos[failed, ax_a], est_pos[failed, ax_b], "rx", ms=9, mew=2,
                     label="failed frames")
    ax_traj.set_xlabel(label_a)
    ax_traj.set_ylabel(label_b)
    ax_traj.set_aspect("equal", adjustable="datalim")
    ax_traj.set_title("trajectory, top view")
    ax_traj.grid(alpha=0.3)
    ax_traj.legend(fontsize=8)

    def series(key):
        values = np.array([s.get(key) if s.get(key) is not None else np.nan for s in stats], float)
        if len(values):
            values[0] = np.nan  # the first frame has no predecessor: nothing was registered
        return values

    ax_inl.plot(idx, series("num_inliers"), ".-", color="tab:blue", label="inliers")
    ax_inl.plot(idx, series("num_correspondences"), ".-", color="tab:gray", alpha=0.7,
                label="correspondences")
    ax_inl.set_yscale("symlog", linthresh=10)
    ax_inl.set_title("RANSAC inliers per frame")
    ax_inl.set_xlabel("frame")

    trans, rot = rpe(est, ref)
    has_rpe = np.isfinite(trans).any()
    ax_t.plot(idx, trans * 100, ".-", color="tab:orange")
    ax_t.set_title("RPE translation vs reference [cm]" if has_rpe else "RPE: no reference in log")
    ax_t.set_xlabel("frame")
    ax_r.plot(idx, rot, ".-", color="tab:purple")
    ax_r.set_title("RPE rotation vs reference [deg]" if has_rpe else "RPE: no reference in log")
    ax_r.set_xlabel("frame")
    for ax in (ax_inl, ax_t, ax_r):
        ax.grid(alpha=0.3)
        for k in idx[failed]:
            ax.axvspan(k - 0.5, k + 0.5, color="red", alpha=0.25, lw=0)
    if failed.any():
        ax_inl.plot([], [], color="red", alpha=0.25, lw=6, label="failed frame")
    ax_inl.legend(fontsize=8)

    summary = {
        "frames": len(frames),
        "failed": int(failed.sum()),
        "rpe_trans_mean_cm": float(np.nanmean(trans) * 100) if has_rpe else None,
        "rpe_trans_median_cm": float(np.nanmedian(trans) * 100) if has_rpe else None,
        "rpe_trans_max_cm": float(np.nanmax(trans) * 100) if has_rpe else None,
        "rpe_rot_mean_deg": float(np.nanmean(rot)) if has_rpe else None,
        "rpe_rot_median_deg": float(np.nanmedian(rot)) if has_rpe else None,
        "rpe_rot_max_deg": float(np.nanmax(rot)) if has_rpe else None,
    }
    meta = run.metadata
    title = (
        f"{mcap.name}: {summary['frames']} frames on {run.cloud_topic}, "
        f"{summary['failed']} failed — mireg {meta.get('version', '?')}, seed {meta.get('seed', '?')}"
    )
    if has_rpe:
        title += (
            f"\nRPE translation mean {summary['rpe_trans_mean_cm']:.2f} / median "
            f"{summary['rpe_trans_median_cm']:.2f} / max {summary['rpe_trans_max_cm']:.2f} cm;"
            f" rotation mean {summary['rpe_rot_mean_deg']:.2f} / median "
            f"{summary['rpe_rot_median_deg']:.2f} / max {summary['rpe_rot_max_deg']:.2f} deg"
        )
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    plt.close(fig)
    return summary


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("mcap", type=Path, help="output MCAP of `mireg register`")
    p.add_argument("-o", "--output", type=Path, required=True, help="PNG to write")
    p.add_argument("--dpi", type=int, default=110)
    args = p.parse_args(argv)
    try:
        summary = make_report(args.mcap, args.output, args.dpi)
    except (OSError, ValueError) as e:
        raise SystemExit(f"report: {e}") from None
    for key, value in summary.items():
        print(f"{key}: {value if not isinstance(value, float) else round(value, 3)}")
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
