"""``python -m mireg.viewer OUT.mcap``: the same as ``mireg view OUT.mcap``."""

import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main(prog="python -m mireg.viewer"))
