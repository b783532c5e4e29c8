"""The ``mireg`` command of the Python package: the Rust command line, run inside the extension
(``mireg._mireg.cli_main``: the same code as the ``mireg`` binary built by cargo), plus
``mireg view`` (the Rerun viewer, ``pip install "mireg[viewer]"``)."""

from __future__ import annotations

import sys

from . import _mireg


def main(argv: list[str] | None = None) -> int:
    """``mireg ARGS``: exit status 0, 1 when a registration fails its checks, 2 on an error."""
    argv = list(sys.argv if argv is None else argv)
    if len(argv) > 1 and argv[1] == "view":
        try:
            from .viewer.cli import main as view
        except ImportError as e:  # rerun-sdk missing
            print(f"mireg view needs the viewer extra ({e}): pip install \"mireg[viewer]\"",
                  file=sys.stderr)
            return 2
        return view(argv[2:], prog="mireg view")
    sys.stdout.flush()
    return _mireg.cli_main(argv)
