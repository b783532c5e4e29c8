#!/usr/bin/env python3
"""Score a `mireg localize` output against the reference, unaligned, with the official `mcap`
reader: the localised poses (`…/pose`, in the prior's world: the prior run's first frame) against
where the reference puts each frame relative to the prior's first frame. Both files must carry
the same reference (`--reference-topic`, default `/ground_truth/pose`) in one world, as logs cut
from one source do.

Prints the position RMSE and maximum over the placed frames (no alignment of any kind), the
rotation maximum, the frames per status, and for comparison the prior's own ATE (aligned) and
its own poses' RMSE against the reference from its first frame (unaligned, as the localised
poses are scored).

Usage: python3 tools/toolbox.py localize-error OUT.mcap PRIOR.mcap [--json]
(venv: `bash tools/setup_venv.sh merge`).
"""

import argparse
import json
import sys
from collections import Counter

import numpy as np
from mcap.reader import make_reader

from merge_ate import align, angle_deg, ate, read_poses


def main(argv):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("output")
    ap.add_argument("prior")
    ap.add_argument("--reference-topic", default="/ground_truth/pose")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    with open(args.output, "rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}["mireg_localize"]
    pose_topic, status_topic = meta["pose_topic"], meta["localization_topic"]
    out = read_poses(args.output, [pose_topic, args.reference_topic])
    est, ref = out[pose_topic], out[args.reference_topic]
    with open(args.output, "rb") as f:
        statuses = Counter(json.loads(m.data)["status"]
                           for _, _, m in make_reader(f).iter_messages(topics=[status_topic]))
    prior = read_poses(args.prior, ["/mireg/pose_optimized", "/mireg/pose", args.reference_topic])
    pref = prior[args.reference_topic]
    origin = np.linalg.inv(pref[min(pref)])
    stamps = sorted(set(est) & set(ref))
    if not stamps:
        sys.exit(f"{args.output}: no placed frame with a reference pose")
    errs, rots = [], []
    for s in stamps:
        truth = origin @ ref[s]
        d = np.linalg.inv(truth) @ est[s]
        errs.append(np.linalg.norm(d[:3, 3]))
        rots.append(angle_deg(d))
    own = prior["/mireg/pose_optimized"] or prior["/mireg/pose"]
    common = sorted(set(own) & set(pref))
    e = np.array([own[s][:3, 3] for s in common])
    r = np.array([pref[s][:3, 3] for s in common])
    # The prior's own poses against the reference from its first frame, unaligned as well: how
    # well the map itself is placed in its own world.
    own_unaligned = [np.linalg.norm((np.linalg.inv(origin @ pref[s]) @ own[s])[:3, 3]) for s in common]
    result = {"placed": len(stamps), "statuses": dict(statuses),
              "rmse_m": float(np.sqrt(np.mean(np.square(errs)))), "max_m": float(max(errs)),
              "max_deg": float(max(rots)), "prior_ate_m": ate(e, r, align(e, r)),
              "prior_unaligned_rmse_m": float(np.sqrt(np.mean(np.square(own_unaligned))))}
    if args.json:
        print(json.dumps(result, indent=2))
        return
    print(f"{result['placed']} frames placed {dict(statuses)}: position error (unaligned) RMSE "
          f"{result['rmse_m']:.4f} m, max {result['max_m']:.4f} m, rotation max {result['max_deg']:.3f} deg; "
          f"prior's own ATE {result['prior_ate_m']:.4f} m, its own poses unaligned "
          f"{result['prior_unaligned_rmse_m']:.4f} m")


if __name__ == "__main__":
    main(sys.argv[1:])
