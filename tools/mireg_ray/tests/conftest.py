"""What the driver's tests share: the mireg binary they run (``MIREG_BIN``, else mireg on PATH,
else target/release/mireg), skipping when there is none."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from mireg_ray import common


@pytest.fixture(scope="module")
def binary():
    b = common.mireg_bin()
    if not Path(b).exists() and shutil.which(b) is None:
        pytest.skip(f"no mireg binary at {b}: build it or set MIREG_BIN")
    return b
