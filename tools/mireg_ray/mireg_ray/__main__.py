"""Command line: ``python -m mireg_ray run|segments …`` (see the package doc and docs/RAY.md).
Arguments after ``--`` go to ``mireg register`` unchanged."""

from __future__ import annotations

import argparse
import sys

from . import run, segments


def parse(argv: list[str]):
    if "--" in argv:
        i = argv.index("--")
        argv, mireg_args = argv[:i], argv[i + 1:]
    else:
        mireg_args = []
    p = argparse.ArgumentParser(prog="python -m mireg_ray", description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="command", required=True)

    def cluster(q):
        q.add_argument("--address", help="Ray cluster address (default: start a local one)")
        q.add_argument("--local-cpus", type=int, help="CPUs of the local cluster (default: all)")
        q.add_argument("--cpus-per-task", type=int, default=1,
                       help="CPUs Ray reserves per task, and mireg's threads (default 1)")
        q.add_argument("--retries", type=int, default=3,
                       help="retries of a task whose worker or mireg process was lost (default 3)")

    r = sub.add_parser("run", help="register every log a glob names, one Ray task each")
    r.add_argument("glob", help="e.g. 'logs/**/*.mcap' or 's3://bucket/logs/*.mcap' (quote it); "
                                "bag directories match too")
    r.add_argument("--out", required=True,
                   help="output directory or URL, e.g. s3://bucket/out (manifest.jsonl inside)")
    r.add_argument("--storage-option", action="append", metavar="KEY=VALUE",
                   help="an fsspec storage option for s3:// (or other) URLs, repeatable, e.g. "
                        "endpoint_url=http://127.0.0.1:9000 for an S3-compatible store")
    r.add_argument("--merge", metavar="DIR",
                   help="then merge the outputs into DIR: the logs are sessions of one site; each "
                        "pair of sessions is linked in a task (`mireg merge --pair`, files and "
                        "manifest in DIR/links), the merge solved on the driver; a local folder")
    cluster(r)
    s = sub.add_parser("segments", help="register one long log in parallel segments and stitch")
    s.add_argument("log")
    s.add_argument("--segments", type=int, required=True, help="number of segments K")
    s.add_argument("--overlap", type=int, default=24,
                   help="frames shared by consecutive segments (default 24): the later segment "
                        "registers them to warm its local map before its first output frame")
    s.add_argument("--out", required=True, help="stitched output MCAP")
    cluster(s)
    return p.parse_args(argv), mireg_args


def main(argv=None) -> int:
    args, mireg_args = parse(sys.argv[1:] if argv is None else argv)
    if args.command == "run":
        return run.main(args, mireg_args)
    return segments.main(args, mireg_args)


if __name__ == "__main__":
    sys.exit(main())
