"""The ``posetrack`` command line: ``demo``, ``generate``, ``track``."""

from __future__ import annotations

import argparse
import sys


def _demo(args) -> int:
    from ._demo import run_demo

    run_demo(
        args.out,
        frames=args.frames,
        methods=tuple(args.methods.split(",")),
        occlusion_levels=tuple(int(x) for x in args.occlusion.split(",")),
        motion=args.motion,
        seed=args.seed,
        progress=not args.quiet,
    )
    return 0


def _generate(args) -> int:
    from . import synth

    seq = synth.generate(
        args.seed, motion=args.motion, n_frames=args.frames, occlusion_level=args.occlusion,
        width=args.width, height=args.height, progress=not args.quiet,
    )  # fmt: skip
    synth.save(seq, args.out)
    print(f"wrote {len(seq.depth)} frames to {args.out}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="posetrack",
        description="3D human pose tracking from RGB-D video and 2D keypoints (Makris & Argyros).",
    )
    sub = p.add_subparsers(dest="command", required=True)

    d = sub.add_parser(
        "demo", help="generate a synthetic RGB-D sequence, track it, print a table, write pictures"
    )
    d.add_argument(
        "--out",
        default="posetrack-demo",
        help="folder for pictures and numbers (default: %(default)s)",
    )
    d.add_argument(
        "--frames", type=int, default=60, help="frames per sequence (default: %(default)s)"
    )
    d.add_argument(
        "--methods", default="lvm,mht_h", help="comma-separated methods (default: %(default)s)"
    )
    d.add_argument(
        "--occlusion",
        default="0,2",
        help="comma-separated occlusion levels 0-4 (default: %(default)s)",
    )
    d.add_argument("--motion", default="walk", help="built-in motion (default: %(default)s)")
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--quiet", action="store_true", help="no progress bars")
    d.set_defaults(func=_demo)

    g = sub.add_parser(
        "generate",
        help="write a synthetic recording folder (depth PNGs, OpenPose JSON, intrinsics)",
    )
    g.add_argument("out", help="output folder")
    g.add_argument("--frames", type=int, default=60)
    g.add_argument("--motion", default="walk")
    g.add_argument("--occlusion", type=int, default=0)
    g.add_argument("--width", type=int, default=640)
    g.add_argument("--height", type=int, default=480)
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--quiet", action="store_true")
    g.set_defaults(func=_generate)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
