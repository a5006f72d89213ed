"""``atris bench sim``: simulator sub-frames per second, per scene, image size and noise.

    atris bench sim --json
    atris bench sim --frames 100 --scenes indoor_lab parking_pedestrian

Rows (``--json`` prints the list): ``scene``, ``width``, ``height``, ``noise``,
``dynamic`` (flicker, interferers or motion present), ``frames_per_s`` (rendering only,
chips alternating) and ``setup_s`` (the one-off static render). Each scene is run at its
own 640×400 and at 2048×1088 (the paper's CMV2000; focal length scaled with the width),
with noise on and off. A static, noise-free scene reuses its prepared frames, so it costs
a fraction of a noisy or dynamic one.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from typing import Any

from atris_node.sim import Scene, Simulator, load_scene

SIZES = ((640, 400), (2048, 1088))
DEFAULT_SCENES = ("indoor_lab", "parking_pedestrian")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print the rows as a JSON list")
    parser.add_argument("--frames", type=int, default=120, help="sub-frames per row")
    parser.add_argument("--scenes", nargs="+", default=list(DEFAULT_SCENES),
                        help="scene names or paths")
    parser.add_argument("--small", action="store_true", help="only 640x400")


def resized(scene: Scene, width: int, height: int) -> Scene:
    """``scene`` with its camera at ``width``×``height`` (focal scaled, centred)."""
    cam = scene.camera
    scale = width / cam.width_px
    camera = replace(cam, width_px=width, height_px=height, focal_px=cam.focal_px * scale,
                     cx_px=(width - 1) / 2.0, cy_px=(height - 1) / 2.0,
                     pixel_pitch_um=cam.pixel_pitch_um / scale)
    return replace(scene, camera=camera)


def measure(scene: Scene, noise: bool, frames: int) -> dict[str, Any]:
    """One row: set-up time and rendering rate of ``frames`` sub-frames."""
    sim = Simulator(replace(scene, noise=noise), seed=1)
    start = time.perf_counter()
    sim.render(0, 0)
    sim.render(1, 1)
    setup_s = time.perf_counter() - start
    start = time.perf_counter()
    for sequence in range(2, frames + 2):
        sim.render(sequence, sequence & 1)
    elapsed = time.perf_counter() - start
    return {"scene": scene.name, "width": scene.camera.width_px,
            "height": scene.camera.height_px, "noise": noise, "dynamic": sim.dynamic,
            "frames_per_s": round(frames / elapsed, 1), "setup_s": round(setup_s, 3)}


def run(args: argparse.Namespace) -> int:
    rows = []
    sizes = SIZES[:1] if args.small else SIZES
    for name in args.scenes:
        base = load_scene(name)
        for width, height in sizes:
            scene = resized(base, width, height)
            for noise in (True, False):
                row = measure(scene, noise, args.frames)
                rows.append(row)
                if not args.json:
                    print(f"{row['scene']:>20} {width}x{height} noise={noise!s:5} "
                          f"{row['frames_per_s']:8.1f} sub-frames/s (setup {row['setup_s']} s)")
    if args.json:
        print(json.dumps(rows, indent=1))
    return 0
