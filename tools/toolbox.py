#!/usr/bin/env python3
"""mireg's tools as one command: ``python3 tools/toolbox.py COMMAND [ARGS...]``.

Every script of tools/ is a subcommand, named after its file (``make_loop_logs.py`` is
``make-loop-logs``). The toolbox runs it with the Python of the venv its optional-dependency group
of tools/pyproject.toml makes (``tools/.venv-GROUP``, or any ``tools/.venv-...`` that includes the
group, e.g. ``.venv-python-ray`` for ``python``), creating that venv with tools/setup_venv.sh the
first time. Shell tools run with bash. The toolbox itself needs only the standard library.

    python3 tools/toolbox.py                      # the commands, by family, with their venvs
    python3 tools/toolbox.py make-loop-logs --all --out-dir /tmp
    python3 tools/toolbox.py seed-logs target/release/mireg /tmp/loop_kaist03.mcap
    python3 tools/toolbox.py setup odometry       # a venv without running anything
    python3 tools/toolbox.py COMMAND --help       # the script's own help

``MIREG_TOOLS_PYTHON=/path/to/python`` runs Python tools with that interpreter instead.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent

# Script -> the optional-dependency group of tools/pyproject.toml whose venv runs it (None: the
# standard library is enough, any python3).
GROUPS = {
    "add_fake_loops.py": "python",
    "bench_livox.py": None,
    "bench_python_pair.py": "python",
    "bench_read_clouds.py": "python",
    "bench_sessions.py": "merge",
    "bench_speed.py": "odometry",
    "calibrate_covariance.py": "mcap",
    "check_3dmatch_gt.py": "peers",
    "check_bag_output.py": "rosbags",
    "check_evo.py": "evo",
    "check_kitti_reference.py": "peers",
    "check_map_open3d.py": "map",
    "check_mcap.py": "mcap",
    "check_pose_graph_gtsam.py": "gtsam",
    "check_salvage.py": "rosbags",
    "compare_deskew.py": "mcap",
    "compare_fps.py": "odometry",
    "compare_kiss_icp.py": "odometry",
    "compare_loops.py": "loops",
    "compare_open3d.py": "peers",
    "fpfh_vs_open3d.py": "peers",
    "leg_error.py": "loops",
    "localize_error.py": "merge",
    "make_bag_fixtures.py": "rosbags",
    "make_big_bag.py": "rosbags",
    "make_fixture_mcap.py": "mcap",
    "make_fpfh_golden.py": "peers",
    "make_icl_fixture.py": None,
    "make_kaist03_mcap.py": "mcap",
    "make_livox_log.py": "rosbags",
    "make_loop_logs.py": "mcap",
    "merge_ate.py": "merge",
    "plot_simulation.py": "peers",
    "plot_sweep.py": "peers",
    "repeat_log.py": "mcap",
    "seed_logs.py": "odometry",
    "seed_sweep.py": "peers",
    "segment_accuracy.py": "ray",
    "bench_logs.sh": None,
    "bomb_inputs.sh": None,
    "fuzz.sh": None,
    "pose_md5.sh": None,
}
# Modules other tools run or import, not commands of their own.
HELPERS = {"livox_scene.py", "mireg_run.py", "peer_open3d_match_icp.py", "toolbox.py"}
# Families, by the file name's first word.
FAMILIES = [
    ("make", "build fixtures and test logs"),
    ("check", "check outputs and references with independent readers"),
    ("compare", "side by side with the peers"),
    ("bench", "benchmarks"),
    ("plot", "plots"),
    ("", "score, edit and probe outputs"),
]


def command_name(script: str) -> str:
    return Path(script).stem.replace("_", "-")


def scripts() -> list[str]:
    """The tools' scripts on disk; fails when one is in neither table, or a table names a
    missing one (so that a new script gets a group)."""
    on_disk = {p.name for p in HERE.iterdir() if p.suffix in (".py", ".sh")}
    on_disk.discard("setup_venv.sh")
    unknown = sorted(on_disk - set(GROUPS) - HELPERS)
    missing = sorted(set(GROUPS) - on_disk)
    if unknown or missing:
        sys.exit(
            f"tools/toolbox.py: scripts without a group in GROUPS: {unknown or 'none'}; "
            f"GROUPS names missing scripts: {missing or 'none'}"
        )
    return sorted(GROUPS)


def summary(script: str) -> str:
    """The first line of a script's docstring (Python) or of its header comment (shell)."""
    text = (HERE / script).read_text(encoding="utf-8")
    if script.endswith(".py"):
        doc = ast.get_docstring(ast.parse(text)) or ""
        line = doc.strip().splitlines()[0] if doc.strip() else ""
    else:
        comments = [ln[1:].strip() for ln in text.splitlines()[1:] if ln.startswith("#")]
        line = comments[0] if comments else ""
    return line.replace("``", "`")


def family(script: str) -> str:
    first = Path(script).stem.split("_")[0]
    known = {prefix for prefix, _ in FAMILIES if prefix}
    if first in ("seed", "fpfh"):
        return "compare"
    return first if first in known else ""


def listing() -> str:
    names = scripts()
    lines = [__doc__.strip().splitlines()[0], "", "commands:"]
    for prefix, title in FAMILIES:
        members = [s for s in names if family(s) == prefix]
        lines.append(f"\n  {title}:")
        for s in members:
            where = "bash" if s.endswith(".sh") else f"venv {GROUPS[s]}" if GROUPS[s] else "python3"
            lines.append(f"    {command_name(s):24s} {summary(s)[:90]}  [{where}]")
    lines.append("\n  setup GROUP...            make the venv of tools/pyproject.toml's groups")
    lines.append("\n`python3 tools/toolbox.py COMMAND --help` shows a command's own help.")
    return "\n".join(lines)


def venv_python(group: str) -> Path:
    """The Python of a venv holding `group`, made with tools/setup_venv.sh when there is none."""
    for venv in sorted(HERE.glob(".venv-*")):
        python = venv / "bin" / "python"
        if group in venv.name.removeprefix(".venv-").split("-") and python.exists():
            return python
    print(f"toolbox: making tools/.venv-{group} (bash tools/setup_venv.sh {group})", file=sys.stderr)
    subprocess.run(["bash", str(HERE / "setup_venv.sh"), group], check=True)
    return HERE / f".venv-{group}" / "bin" / "python"


def main(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help", "help", "list"):
        print(listing())
        return 0
    command, rest = argv[0], argv[1:]
    if command == "setup":
        return subprocess.call(["bash", str(HERE / "setup_venv.sh"), *rest])
    by_name = {command_name(s): s for s in scripts()}
    script = by_name.get(command)
    if script is None:
        close = [n for n in by_name if command in n or n.startswith(command.split("-")[0])]
        hint = f" (did you mean {', '.join(close[:4])}?)" if close else ""
        print(f"toolbox: no command {command!r}{hint}; `python3 tools/toolbox.py` lists them",
              file=sys.stderr)
        return 2
    path = HERE / script
    if script.endswith(".sh"):
        return subprocess.call(["bash", str(path), *rest])
    group = GROUPS[script]
    python = os.environ.get("MIREG_TOOLS_PYTHON") or (
        str(venv_python(group)) if group else sys.executable
    )
    return subprocess.call([python, str(path), *rest])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
