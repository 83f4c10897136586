"""Render a Rerun recording at chosen global `step`s to PNGs in a headless native viewer (software Vulkan
is enough): `rerun.experimental.ViewerClient` of rerun-sdk 0.41. `baselines/screenshots.py` is its CLI."""

from __future__ import annotations

import os
import socket
import sys
import time
import warnings

from rerun.experimental import ViewerClient


def screenshots(
    path: str, steps: list[int], out_dir: str, timeout_s: float = 60.0, settle_tries: int = 20
) -> list[str]:
    """Render the recording at `path` in a headless native viewer (software Vulkan is enough), with its
    stored blueprint, paused at each global `step`, to `out_dir/<name>_step<k>.png`; returns the PNG paths.

    Uses `rerun.experimental.ViewerClient` (rerun-sdk 0.41): spawn `rerun --headless`, open the file,
    wait until it is loaded, then move the time cursor and take screenshots until two in a row match."""
    if not os.path.isfile(path):
        raise FileNotFoundError(f"no recording at {path!r}")
    os.makedirs(out_dir, exist_ok=True)
    with socket.socket() as probe:  # a free port, so that several viewers (or a user's own) can coexist
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    executable = os.path.join(os.path.dirname(sys.executable), "rerun")
    viewer = ViewerClient.spawn(
        headless=True,
        port=port,
        hide_welcome_screen=True,
        executable_path=executable if os.path.exists(executable) else None,
    )
    try:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                viewer.get_state()
                break
            except Exception:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.5)
        viewer.open(os.path.abspath(path))
        while viewer.get_state().loading:
            if time.monotonic() > deadline:
                raise TimeoutError(f"the viewer did not finish loading {path!r} in {timeout_s} s")
            time.sleep(0.5)
        last = viewer.get_state().recordings[0].timelines
        end = next((t.end for t in last if t.name == "step"), None)
        written = []
        name = os.path.splitext(os.path.basename(path))[0]
        for step in steps:
            if end is not None and not 0 <= step <= end:
                raise ValueError(f"step={step} is outside the recording's steps 0..{end}")
            viewer.set_time("step", sequence=int(step), play_state="paused")
            # The viewer fetches chunks on demand after loading the index: shoot until the picture settles.
            image, previous = viewer.take_screenshot(), None
            for _ in range(settle_tries):
                if image == previous:
                    break
                time.sleep(0.5)
                image, previous = viewer.take_screenshot(), image
            for view in viewer.get_state().views:  # what the viewer could not show, e.g. a missing pinhole
                for report in view.reports:
                    warnings.warn(f"step {step}, view {view.name!r}: {report.severity}: {report.summary}", stacklevel=2)
            png = os.path.abspath(os.path.join(out_dir, f"{name}_step{step}.png"))
            with open(png, "wb") as f:
                f.write(image)
            written.append(png)
        return written
    finally:
        viewer.quit()
