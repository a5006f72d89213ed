"""``atris calib simulate SCENE --out DIR``: a capture set with its truth, no hardware."""

from __future__ import annotations

import argparse
from pathlib import Path

from atris_node.errors import CalibrationError
from calib.commands.common import add_board_arguments, board_from_args, print_result
from calib.simulate import (
    BUILT_IN_SCENE,
    DEFAULT_DISTANCES_M,
    DEFAULT_VERIFY_M,
    SimulationSettings,
    simulate_capture_set,
)


def _distances(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(v) for v in text.split(","))
    except ValueError as exc:
        raise CalibrationError(f"--distances takes metres separated by commas, got {text!r}"
                               ) from exc


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", help=f"scene name ({BUILT_IN_SCENE!r} is built in)")
    parser.add_argument("--out", type=Path, required=True, help="folder to write")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--views", type=int, default=12, help="board views for intrinsics")
    parser.add_argument("--poses", type=int, default=8, help="board poses with the laser")
    parser.add_argument("--distances", default=",".join(map(str, DEFAULT_DISTANCES_M)),
                        help="flat-target distances, metres, comma separated")
    parser.add_argument("--verify-distance", type=float, default=DEFAULT_VERIFY_M)
    parser.add_argument("--glints", type=int, default=40, help="laser glints per capture")
    add_board_arguments(parser)


def run(args: argparse.Namespace) -> int:
    settings = SimulationSettings(intrinsic_views=args.views, board_poses=args.poses,
                                  distances_m=_distances(args.distances),
                                  verify_distance_m=args.verify_distance,
                                  glints=args.glints, seed=args.seed)
    captures = simulate_capture_set(args.scene, args.out, settings, board_from_args(args))
    print_result({"captures": str(captures.root / "captures.toml"),
                  "truth": str(captures.path(captures.truth)),
                  "board_views": len(captures.intrinsics), "flat_targets": len(captures.flat),
                  "board_poses": len(captures.board_laser)}, as_json=False)
    return 0
