"""What the driver's tests share: the mireg command they run (``MIREG_BIN``, else the installed
mireg package's command, else mireg on PATH), skipping when there is none."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from mireg_ray import common


@pytest.fixture(scope="module")
def binary():
    try:
        b = common.mireg_bin()
    except SystemExit as e:
        pytest.skip(str(e))
    if not Path(b).exists() and shutil.which(b) is None:
        pytest.skip(f"no mireg binary at {b}: build it or set MIREG_BIN")
    return b
