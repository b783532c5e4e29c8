#!/usr/bin/env python3
"""Sessions from real logs, merged and localised, scored against the reference (issue "Many logs,
one map"). For each log: the first half and the second half of its clouds registered as two
sessions, each in its own world (`mireg register --start/--end --copy-window`: a segment's world
is its first frame; mireg is not told how they relate); the whole log registered as one, for
comparison. Then

* `mireg merge A B`, scored by tools/merge_ate.py: the joint ATE (one alignment for both) against
  the whole log's loop-closed ATE, and the accepted links against the reference;
* `mireg localize LOG --map B` (the whole raw log in a prior map of its second half), scored by
  tools/localize_error.py: unaligned position error in the prior's world; and the same with the
  prior as a map file (`mireg map B -o B.ply`, cut into tiles by localize);
* a foreign pair must stay apart: of the two logs whose voxels (the first cloud's median range
  / 40, `register` derives it) differ most, at least `FOREIGN_VOXEL_RATIO` times (an indoor and
  an outdoor log), the first half of one with the second half of the other; and the one log
  localised in the other's second half (run and map file) must localise no frame. Logs of one
  kind of scene (e.g. all KAIST03) have no foreign pair: the bench says so and skips it.

A log that does not localise in its own second half (every frame `lost`) gets a row of 0 placed
frames and no error, instead of ending the bench.

Timings are wall-clock seconds of each command on this machine. Logs: the ICL fixture and, when
given, logs from tools/make_loop_logs.py (out-and-back: the halves are the way out and the way
back, different scans of the same places).

Usage: python3 tools/toolbox.py bench-sessions [--mireg BIN] [--work DIR] LOG...
(venv: `bash tools/setup_venv.sh merge`).
"""

import argparse
import json
import pathlib
import subprocess
import sys
import time

import localize_error
import merge_ate
import mireg_run

# Two logs are a foreign pair (different places, which must not join) when their voxels differ
# at least this many times: a room (ICL, micro211: ~5 cm) and a street (KAIST03: ~0.37 m).
FOREIGN_VOXEL_RATIO = 2.0


def foreign_pair(voxels):
    """The indices (i, j) of the two logs whose voxels differ most, when at least
    FOREIGN_VOXEL_RATIO times (the earliest such pair, i < j); None otherwise."""
    pairs = [(max(a, b) / min(a, b), i, j) for i, a in enumerate(voxels)
             for j, b in enumerate(voxels) if i < j]
    best = max(pairs, key=lambda p: (p[0], -p[1], -p[2]), default=None)
    return best[1:] if best and best[0] >= FOREIGN_VOXEL_RATIO else None


def run(cmd):
    t = time.perf_counter()
    p = subprocess.run([str(c) for c in cmd], capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"{' '.join(map(str, cmd))}: {p.stderr}")
    return time.perf_counter() - t, p.stdout


def clouds(mireg, log):
    _, out = run([mireg, "info", log])
    for line in out.splitlines():
        if line.startswith("point clouds:"):
            return int(line.split(",")[1].split()[0])
    sys.exit(f"{log}: no point cloud topic")


def json_of(tool, argv):
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        tool.main(argv + ["--json"])
    return json.loads(buf.getvalue())


def placed_error(localized, prior):
    """tools/localize_error.py's scores of `localized` in `prior`; where no frame was placed
    (the log did not localise: every frame `lost`), a row that says so instead."""
    try:
        return json_of(localize_error, [str(localized), str(prior)])
    except SystemExit as e:
        print(f"{e}", file=sys.stderr)
        return {"placed": 0, "statuses": {}, "rmse_m": float("nan"),
                "prior_unaligned_rmse_m": float("nan")}


def main(argv):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("logs", nargs="+", type=pathlib.Path)
    ap.add_argument("--mireg", default=mireg_run.default_binary())
    ap.add_argument("--work", type=pathlib.Path, default=pathlib.Path("/tmp/mireg-sessions"))
    args = ap.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    m = args.mireg
    rows, halves, voxels = [], [], []
    for log in args.logs:
        name = log.stem
        n = clouds(m, log)
        h = (n + 1) // 2
        a, b, whole = (args.work / f"{name}_{x}.mcap" for x in ("a", "b", "whole"))
        run([m, "register", log, "--end", h, "--copy-window", "-o", a, "--force", "--quiet"])
        run([m, "register", log, "--start", h, "--copy-window", "-o", b, "--force", "--quiet"])
        t_reg, js = run([m, "register", log, "-o", whole, "--force", "--quiet", "--json"])
        voxels.append(json.loads(js)["voxel_m"])
        _, ev = run([m, "evaluate", whole, "--json"])
        whole_ate = json.loads(ev)["ate_rmse_m"]
        merged = args.work / f"{name}_merged"
        t_merge, _ = run([m, "merge", a, b, "-o", merged, "--force"])
        mr = json_of(merge_ate, [str(merged)])
        loc = args.work / f"{name}_localized.mcap"
        t_loc, _ = run([m, "localize", log, "--map", b, "-o", loc, "--force"])
        lr = placed_error(loc, b)
        ply = args.work / f"{name}_b.ply"
        run([m, "map", b, "-o", ply, "--force"])
        loc_map = args.work / f"{name}_localized_in_map.mcap"
        t_loc_map, _ = run([m, "localize", log, "--map", ply, "-o", loc_map, "--force"])
        lm = placed_error(loc_map, b)
        g = mr["groups"]
        rows.append({
            "log": name, "clouds": n, "groups": len(g),
            "joint_ate_m": g[min(g)]["joint_ate_m"], "whole_ate_m": whole_ate,
            "links": mr["links"], "merge_s": t_merge, "register_s": t_reg,
            "localize": lr, "localize_s": t_loc, "localize_map": lm, "localize_map_s": t_loc_map,
        })
        halves.append((a, b))
    foreign = None
    pair = foreign_pair(voxels)
    if pair:
        i, j = pair
        fdir = args.work / "foreign_merged"
        run([m, "merge", halves[i][0], halves[j][1], "-o", fdir, "--force"])
        report = json.loads((fdir / "merge_report.json").read_text())
        foreign = {"pair": [halves[i][0].name, halves[j][1].name], "groups": report["groups"],
                   "links_accepted": report["links_accepted"], "log": args.logs[i].name}
        # And log i localised in log j's map, as a run and as a map file: no frame may be
        # localised (the target: 0 on a foreign map).
        foreign["localize"] = []
        for prior in (halves[j][1], args.work / f"{args.logs[j].stem}_b.ply"):
            out = args.work / f"foreign_localized_{prior.suffix[1:]}.mcap"
            _, js = run([m, "localize", args.logs[i], "--map", prior, "-o", out, "--force",
                         "--json"])
            summary = json.loads(js)
            foreign["localize"].append((prior.name, summary["localized"], summary["frames"]))
    print("| log | clouds | merge: groups | joint ATE | one log's ATE | ratio | links (wrong) | "
          "merge s | localize: placed (localized) | unaligned RMSE | prior's own unaligned | "
          "localize s | register s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        lr = r["localize"]
        print(f"| {r['log']} | {r['clouds']} | {r['groups']} | {100 * r['joint_ate_m']:.2f} cm | "
              f"{100 * r['whole_ate_m']:.2f} cm | {r['joint_ate_m'] / r['whole_ate_m']:.2f} | "
              f"{r['links']['accepted']} ({r['links']['wrong']}) | {r['merge_s']:.2f} | "
              f"{lr['placed']} ({lr['statuses'].get('localized', 0)}) | {100 * lr['rmse_m']:.2f} cm | "
              f"{100 * lr['prior_unaligned_rmse_m']:.2f} cm | {r['localize_s']:.2f} | {r['register_s']:.2f} |")
    print("\nThe prior as a map file (`mireg map B -o B.ply`):\n")
    print("| log | placed (localized) | unaligned RMSE | localize s |")
    print("|---|---|---|---|")
    for r in rows:
        lm = r["localize_map"]
        print(f"| {r['log']} | {lm['placed']} ({lm['statuses'].get('localized', 0)}) | "
              f"{100 * lm['rmse_m']:.2f} cm | {r['localize_map_s']:.2f} |")
    if foreign:
        print(f"\nforeign pair {foreign['pair']}: {foreign['groups']} groups, "
              f"{foreign['links_accepted']} links accepted")
        for prior, localized, frames in foreign["localize"]:
            print(f"{foreign['log']} localised in the foreign map {prior}: {localized} of "
                  f"{frames} frames localized")
    elif len(rows) > 1:
        print(f"\nno foreign pair: every log's voxel is within {FOREIGN_VOXEL_RATIO:g}x of the "
              f"others' ({', '.join(f'{v:.3f}' for v in voxels)} m); give an indoor and an "
              "outdoor log")


if __name__ == "__main__":
    main(sys.argv[1:])
