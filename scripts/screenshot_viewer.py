"""Open a recording in the real Rerun viewer, headless, and save a screenshot of the view it opens with.

This is how ``docs/viewer.png`` is made; it shows what a new user sees on opening a run's recording, with the
layout the learner sends (``monitor/layout.py``) and nothing configured by hand.

Needs, besides the project's venv (its rerun-sdk bundles the viewer):

* an X server and a Vulkan driver; on Debian or Ubuntu ``apt-get install -y xvfb mesa-vulkan-drivers`` (Mesa's
  software rasterizer, lavapipe, is enough: no GPU needed). The script starts ``Xvfb`` itself when ``DISPLAY`` is
  unset.
* a recording, e.g. from a short run: ``.venv/bin/ennc-ql up --duration 480 --rerun save runs/demo.rrd``.

Usage::

    .venv/bin/python scripts/screenshot_viewer.py runs/demo.rrd docs/viewer.png [--size 1800x1100]

The picture comes from the viewer's own API (``rerun.experimental.ViewerClient.save_screenshot``): a screen grab of
Xvfb comes out black, as the viewer draws through Vulkan, not into the X framebuffer. It is then stored with 256
colours (a quarter of the size, no visible loss on the viewer's flat colours). The script also prints what the
viewer reports: each view with any warning it shows, and where the time cursor sits on each timeline.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from PIL import Image
from rerun.experimental import ViewerClient

from monitor.recordings import rerun_cli
from tools.system import free_port

DISPLAY = ":99"
"""The display an Xvfb started by this script serves."""
SETTLE_S = 5.0
"""Seconds the viewer gets, once loaded, to lay out and paint every view (software rendering is slow)."""
TIMEOUT_S = 120.0


def start_xvfb(size: str) -> subprocess.Popen[bytes]:
    """An X server twice the window's size: Xvfb puts the pointer in the middle of its screen, which then lies
    outside the viewer's window (at the top left), so no hover tooltip shows in the picture."""
    if shutil.which("Xvfb") is None:
        sys.exit("DISPLAY is unset and Xvfb is missing: apt-get install -y xvfb mesa-vulkan-drivers")
    width, height = (int(n) for n in size.split("x"))
    xvfb = subprocess.Popen(
        ["Xvfb", DISPLAY, "-screen", "0", f"{2 * width + 20}x{2 * height + 20}x24"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    os.environ["DISPLAY"] = DISPLAY
    time.sleep(1.0)
    return xvfb


def tail(log: Path, lines: int = 15) -> str:
    return "\n".join(log.read_text(errors="replace").splitlines()[-lines:])


def connect_when_loaded(viewer: subprocess.Popen[bytes], url: str, log: Path) -> ViewerClient:
    """A client of ``viewer`` (at ``url``) once it has the whole file: a recording with timelines, nothing loading."""
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline:
        if viewer.poll() is not None:
            sys.exit(
                f"the viewer exited with status {viewer.returncode} (no X display or no Vulkan driver?); the end of "
                f"its log {log}:\n{tail(log)}"
            )
        try:  # the viewer takes a few seconds to start listening, then to load the file
            client = ViewerClient.connect(url)
            state = client.get_state()
        except (ConnectionError, RuntimeError):
            time.sleep(1.0)
            continue
        if state.recordings and state.recordings[0].timelines and not state.loading:
            return client
        time.sleep(1.0)
    sys.exit(f"the viewer did not load the recording within {TIMEOUT_S:.0f} s; the end of its log {log}:\n{tail(log)}")


def report(client: ViewerClient) -> None:
    state = client.get_state()
    for view in state.views:
        problems = "; ".join(f"{r.severity}: {r.summary}" for r in view.reports) or "ok"
        print(f"view {view.name!r} ({view.view_class}, origin {view.origin}): {problems}")
    for recording in state.recordings:
        print(f"time cursor on {recording.current_timeline!r} at {recording.current_time}")
        for timeline in recording.timelines:
            print(f"  timeline {timeline.name} ({timeline.time_type}): {timeline.start} .. {timeline.end}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("recording", type=Path, help="an .rrd file")
    parser.add_argument("png", type=Path, help="where to save the screenshot")
    parser.add_argument("--size", default="1800x1100", help="viewer window size in points (default: 1800x1100)")
    args = parser.parse_args()
    xvfb = start_xvfb(args.size) if not os.environ.get("DISPLAY") else None
    port = free_port()
    # The viewer's own logs (pages of them, from its Rust side) go to a file: this script prints its summary.
    log = Path(tempfile.gettempdir()) / f"screenshot-viewer-{os.getpid()}.log"
    with open(log, "wb") as out:
        viewer = subprocess.Popen(
            [
                *rerun_cli(),
                "--renderer",
                "vulkan",
                "--port",
                str(port),
                "--window-size",
                args.size,
                "--hide-welcome-screen",
                str(args.recording.resolve()),
            ],
            stdout=out,
            stderr=out,
            start_new_session=True,  # the CLI is a wrapper around the viewer binary: stop both through their group
        )
    try:
        client = connect_when_loaded(viewer, f"rerun+http://127.0.0.1:{port}/proxy", log)
        time.sleep(SETTLE_S)
        args.png.parent.mkdir(parents=True, exist_ok=True)
        client.save_screenshot(str(args.png.resolve()))  # the viewer writes it: an absolute path on this host
        report(client)
        with Image.open(args.png) as shot:
            compact = shot.convert("RGB").quantize(256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
        compact.save(args.png, optimize=True)
        print(f"saved {args.png} (the viewer's log: {log})")
    finally:
        with contextlib.suppress(ProcessLookupError):  # a viewer that failed to start has no group left to stop
            os.killpg(viewer.pid, signal.SIGTERM)
        viewer.wait(timeout=30)
        if xvfb is not None:
            xvfb.terminate()
            xvfb.wait(timeout=30)


if __name__ == "__main__":
    main()
