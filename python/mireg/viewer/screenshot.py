"""Headless screenshots and the ``rerun`` binary of the rerun-sdk wheel."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .timeline import TIMELINE

SCREENSHOT_SETTLE_S = 6.0  # seconds between seeking and shooting (toasts fade, views repaint)


def rerun_binary() -> str:
    """The `rerun` CLI shipped in the rerun-sdk wheel (next to this interpreter), else PATH's."""
    candidate = Path(sys.executable).parent / "rerun"
    if candidate.exists():
        return str(candidate)
    found = shutil.which("rerun")
    if found is None:
        raise SystemExit("the `rerun` binary was not found (install rerun-sdk in this venv)")
    return found


def free_port() -> int:
    """A currently free TCP port on 127.0.0.1 (for the headless viewer's gRPC server)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def stop_group(proc: subprocess.Popen) -> None:
    """SIGTERM the process group led by ``proc`` (started with start_new_session=True), SIGKILL
    after 10 s."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            break
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            try:
                os.killpg(proc.pid, 0)  # any member left?
            except ProcessLookupError:
                proc.wait()
                return
            proc.poll()
            time.sleep(0.1)
    proc.wait()


def screenshot(
    rrd: Path, png: Path, window_size: str, timeout: float, end_ns: int | None, colors: int = 0
) -> None:
    """Render ``rrd`` with the headless viewer and write ``png``.

    Starts ``rerun RRD --headless --bind 127.0.0.1 --port <free>`` (the binary from the rerun-sdk
    wheel), drives it with ``rerun.experimental.ViewerClient``: waits until the recording is
    loaded up to ``end_ns`` on ``message_log_time``, puts the time cursor there (paused, so the
    whole accumulated map is shown), lets start-up notifications fade, takes the screenshot and
    stops the viewer. ``colors`` > 0 quantizes the PNG to that many colours (smaller file).
    ``rerun --screenshot-to`` alone shoots the first painted frame, before the
    data has loaded, which is why it is not used here.
    """
    from rerun.experimental import ViewerClient

    png.parent.mkdir(parents=True, exist_ok=True)
    port = free_port()
    cmd = [rerun_binary(), str(rrd), "--headless", "--window-size", window_size,
           "--bind", "127.0.0.1", "--port", str(port)]
    env = dict(os.environ, RERUN_ANALYTICS="0")
    log = tempfile.TemporaryFile(mode="w+")
    # Own session: the wheel's `rerun` is a Python launcher that starts the real viewer binary as a
    # child, so the whole process group has to be stopped afterwards, not just the launcher.
    proc = subprocess.Popen(
        cmd, stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True
    )
    deadline = time.monotonic() + timeout

    def fail(why: str):
        log.seek(0)
        tail = log.read()[-3000:]
        raise SystemExit(
            f"screenshot failed: {why}\n{' '.join(cmd)}\n{tail}\nHeadless rendering needs a "
            "Vulkan driver (mesa lavapipe; Debian: apt-get install mesa-vulkan-drivers)"
        )

    try:
        client, last_error = None, None
        while client is None:
            if proc.poll() is not None:
                fail(f"viewer exited with {proc.returncode}")
            if time.monotonic() > deadline:
                fail(f"no connection to the viewer: {last_error}")
            try:
                candidate = ViewerClient.connect(f"rerun+http://127.0.0.1:{port}/proxy")
                candidate.get_state()
                client = candidate
            except Exception as e:  # not listening yet
                last_error = e
                time.sleep(0.5)
        while True:  # wait for the data (the viewer streams the .rrd in lazily)
            state = client.get_state()
            ends = [t.end for r in state.recordings for t in r.timelines if t.name == TIMELINE]
            if not state.loading and ends and (end_ns is None or max(ends) >= end_ns):
                break
            if time.monotonic() > deadline:
                fail("the recording did not finish loading")
            time.sleep(0.3)
        seek = end_ns if end_ns is not None else max(ends)
        client.set_time(TIMELINE, timestamp=np.datetime64(seek, "ns"), play_state="paused")
        time.sleep(SCREENSHOT_SETTLE_S)  # let the views render and the toasts fade
        data = client.take_screenshot()
        if not data:
            fail("empty screenshot")
        png.write_bytes(data)
        if colors:
            from PIL import Image  # Pillow comes with matplotlib

            with Image.open(png) as image:
                image.convert("RGB").quantize(colors=colors).save(png, optimize=True)
    finally:
        stop_group(proc)
        log.close()
