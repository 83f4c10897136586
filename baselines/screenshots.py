"""Render a Rerun recording at chosen steps to PNGs, without a screen (headless native viewer).

python baselines/screenshots.py recordings/random.rrd --steps 20 60 --out-dir outputs/screenshots
"""

from __future__ import annotations

from dataclasses import dataclass, field

import tyro

from mani_active_vision.recording.screenshots import screenshots


@dataclass
class Args:
    recording: tyro.conf.Positional[str]
    """the .rrd file"""
    steps: list[int] = field(default_factory=lambda: [20, 60])
    """global `step` values to show (the viewer's time cursor)"""
    out_dir: str = "outputs/screenshots"
    """folder for the PNGs (<name>_step<k>.png)"""


def main(args: Args):
    for path in screenshots(args.recording, args.steps, args.out_dir):
        print(f"wrote {path}")


if __name__ == "__main__":
    main(tyro.cli(Args))
