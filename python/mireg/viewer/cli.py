"""Command line of the viewer (``mireg view``, ``python -m mireg.viewer``): arguments, reading,
logging, saving / screenshot / viewer."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from ..run import REFERENCE_TOPIC, read_run
from .scene import log_run, make_blueprint
from .screenshot import rerun_binary, screenshot


def parse_args(argv=None, description: str = "", prog: str | None = None):
    p = argparse.ArgumentParser(
        prog=prog,
        description=description,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Entity paths, the --frame recomputation and --loop are described in "
        "the mireg.viewer package's docstring and docs/VIEWER.md.",
    )
    p.add_argument("mcap", type=Path, help="output MCAP of `mireg register` (or of `mireg "
                   "localize`, or a `mireg merge` folder: their sessions and links)")
    out = p.add_mutually_exclusive_group()
    out.add_argument("--save", type=Path, metavar="OUT.rrd", help="write a .rrd recording")
    out.add_argument("--screenshot", type=Path, metavar="OUT.png", help="headless screenshot")
    p.add_argument("--every", type=int, default=1, metavar="N", help="show every N-th cloud")
    p.add_argument("--max-points", type=int, default=10000, help="points per cloud at most")
    p.add_argument("--frame", type=int, metavar="K", help="recompute and draw the correspondences "
                   "of frame K -> K-1 (registers the pair again with mireg.register_pair)")
    p.add_argument("--loop", type=int, metavar="N", help="draw the clouds of the N-th (0-based) "
                   "/mireg/loops message: the match cloud and the query cloud moved by its "
                   "match_from_query, coloured by nearest-neighbour distance")
    p.add_argument("--hide-rejected", action="store_true",
                   help="draw only the accepted loop edges")
    p.add_argument("--trajectory", choices=("auto", "odometry", "optimized"), default="auto",
                   help="poses placing the clouds, the camera and --map-voxel's map: "
                   "auto = /mireg/pose_optimized when the log has it, else /mireg/pose "
                   "(default %(default)s)")
    p.add_argument("--map", type=Path, metavar="MAP", help="world map to draw as world/map: a "
                   ".ply, .pcd or .npy written by `mireg map OUT.mcap -o MAP`")
    p.add_argument("--map-voxel", type=float, default=0.0, metavar="METRES",
                   help="without --map: build world/map here from every cloud (at most "
                   "--max-points each) placed by --trajectory, voxel-downsampled to this edge; "
                   "0 = no map (default)")
    p.add_argument("--map-max-points", type=int, default=500000,
                   help="points of world/map at most (random subset; default %(default)s)")
    p.add_argument("--cloud-topic", help="PointCloud2 topic (default: from the mireg metadata)")
    p.add_argument("--reference-topic", default=REFERENCE_TOPIC, metavar="TOPIC",
                   help="PoseStamped topic drawn as the reference trajectory, when present "
                        "(default %(default)s)")
    p.add_argument("--point-radius", type=float, default=0.01, help="point radius [m]")
    p.add_argument("--axis-length", type=float, default=0.15, help="pose axes length [m]")
    p.add_argument("--window-size", default="1280x800", help="screenshot size (default %(default)s)")
    p.add_argument("--timeout", type=float, default=180.0, help="screenshot timeout [s]")
    p.add_argument("--png-colors", type=int, default=0, metavar="N",
                   help="quantize the screenshot to N colours (e.g. 256 for docs), 0 = keep")
    args = p.parse_args(argv)
    if args.every < 1:
        p.error("--every must be >= 1")
    if args.max_points < 1 or args.map_max_points < 1:
        p.error("--max-points and --map-max-points must be >= 1")
    if args.map_voxel < 0:
        p.error("--map-voxel must be >= 0")
    if args.frame is not None and args.frame < 1:
        p.error("--frame K needs K >= 1 (frame 0 has no predecessor)")
    if args.loop is not None and args.loop < 0:
        p.error("--loop N needs N >= 0")
    return args


def main(argv=None, description: str = "", prog: str | None = None) -> int:
    if not description:
        from . import __doc__ as doc

        description = doc.split("\n\n")[0]
    args = parse_args(argv, description, prog)
    from . import sessions

    try:
        if sessions.is_merge(args.mcap) or sessions.is_localized(args.mcap):
            if args.screenshot is not None:
                raise SystemExit("mireg view: --screenshot is not available for merge folders "
                                 "and localised logs; use --save")
            return sessions.view(args.mcap, args.save)
    except (OSError, ValueError) as e:
        raise SystemExit(f"mireg view: {e}") from None
    try:
        run = read_run(args.mcap, args.cloud_topic, load_clouds=True,
                       reference_topic=args.reference_topic)
    except (OSError, ValueError) as e:
        raise SystemExit(f"mireg view: {e}") from None
    if args.frame is not None and args.frame >= len(run.frames):
        raise SystemExit(f"--frame {args.frame}: the log has {len(run.frames)} clouds")
    if args.loop is not None and args.loop >= len(run.loops):
        raise SystemExit(f"--loop {args.loop}: the log has {len(run.loops)} loop messages "
                         f"on {run.topics['loops']}")
    if args.trajectory == "optimized" and not run.has_optimized:
        raise SystemExit(f"--trajectory optimized: the log has no {run.topics['optimized']}")
    args.placing = "estimate" if args.trajectory == "odometry" else "optimized"
    has_display = bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    if args.save is None and args.screenshot is None and not has_display:
        raise SystemExit("no display: use --save out.rrd or --screenshot out.png")

    try:
        import rerun as rr
        import rerun.blueprint as rrb
    except ImportError as e:
        raise SystemExit(f"the viewer needs rerun-sdk ({e}): pip install \"mireg[viewer]\"") from None

    rr.init("mireg_view", spawn=False)
    rr.set_log_time_enabled(False)  # no wall-clock "log_time" timeline next to message_log_time
    tmpdir = None
    if args.save is not None:
        rrd = args.save
        rrd.parent.mkdir(parents=True, exist_ok=True)
    else:
        tmpdir = tempfile.TemporaryDirectory(prefix="mireg_view_")
        rrd = Path(tmpdir.name, "view.rrd")
    # Until a sink is set the recording stream buffers everything; rr.save then writes the buffer,
    # so the blueprint (whose camera depends on the data) can be made after logging.
    eyes = log_run(rr, run, args)
    blueprint = make_blueprint(
        rrb, eyes, collapse_panels=args.screenshot is not None, run=run,
        frame=args.frame, loop=args.loop,
    )
    rr.save(rrd, default_blueprint=blueprint)
    n_failed = sum(1 for f in run.frames if f.stats and not f.stats.get("success", True))
    n_accepted = sum(loop.accepted for loop in run.loops)
    print(
        f"{args.mcap}: {len(run.frames)} clouds on {run.cloud_topic}, "
        f"{n_failed} failed, reference {'yes' if run.has_reference else 'no'}, optimised "
        f"trajectory {'yes' if run.has_optimized else 'no'}, loops {len(run.loops)} "
        f"({n_accepted} accepted)",
        file=sys.stderr,
    )
    try:
        if args.save is not None:
            print(f"wrote {rrd}", file=sys.stderr)
        elif args.screenshot is not None:
            # with --frame K / --loop N show the scene at that frame (its pair on top of the map)
            if args.loop is not None:
                end_ns = run.loops[args.loop].log_time
            elif args.frame is not None:
                end_ns = run.frames[args.frame].log_time
            else:
                end_ns = max((f.log_time for f in run.frames), default=None)
                end_ns = max([end_ns or 0] + [loop.log_time for loop in run.loops]) or None
            screenshot(
                rrd, args.screenshot, args.window_size, args.timeout, end_ns, args.png_colors
            )
            print(f"wrote {args.screenshot}", file=sys.stderr)
        else:
            subprocess.run([rerun_binary(), str(rrd), "--bind", "127.0.0.1"], check=False)
    finally:
        if tmpdir is not None:
            tmpdir.cleanup()
    return 0
