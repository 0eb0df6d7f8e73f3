"""``dimacq geometry``: the test's geometry from photographs (and the camera's calibration:
``calibrate-camera``, ``board``).

``dimacq geometry from-photos PHOTOS_DIR --setup SETUP [--tags TAGS.toml] [--camera CAM.toml]
--out GEOMETRY.json`` detects the fiducial tags (AprilTag 36h11 by default) on the triax
blocks, impact jigs, reference plates and scale bar in every photo of ``PHOTOS_DIR``, adjusts
photos, tags and the camera together and writes each triax's orientation and position and each
input's point and line of action with their standard uncertainties, plus ``SETUP`` with that
geometry and its stated uncertainty (key ``setup``: ``dimacq solve`` reads it as a setup file
once extracted, and ``POST /api/digitizer/photo-geometry`` takes the whole file). Photos that
cannot help are named with the fix; a triax or input the photos cannot fix is named with the
number of photos it still needs, and the exit status is 2.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from dimacq.cli.progress import add_quiet, plain

CALIBRATE_HELP = """``dimacq geometry calibrate-camera BOARD_PHOTOS_DIR --board BOARD.toml --out CAM.toml
[--refine]`` finds the board's corners in every photo (a ChArUco board or a chessboard, as
``BOARD.toml`` states), calibrates the camera (OpenCV's pinhole: ``fx, fy, cx, cy`` and
distortion ``k1, k2, p1, p2, k3``) and writes ``CAM.toml`` for ``from-photos --camera``. It prints
each photo's corners, the photos it could not use and why, the RMS reprojection error and each
intrinsic with its standard deviation. A set that cannot support the calibration (fewer than 6
usable photos, too little tilt for the focal length, corners not reaching the image's corners,
too large an RMS) is refused with the fix, nothing is written and the exit status is 2.
"""


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser("geometry", help="geometry of the test from photographs")
    sub = parser.add_subparsers(dest="geometry_command", metavar="ACTION")
    sub.required = True
    fp = sub.add_parser(
        "from-photos",
        help="triax and input geometry from photos of fiducial tags",
        description=plain(__doc__),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    fp.add_argument("photos_dir", type=Path, metavar="PHOTOS_DIR", help="folder of the photos")
    fp.add_argument("--setup", type=Path, required=True, metavar="SETUP", help="setup file")
    fp.add_argument(
        "--tags",
        type=Path,
        default=None,
        metavar="TAGS.toml",
        help="tags file (default: PHOTOS_DIR/tags.toml, else PHOTOS_DIR/../tags.toml)",
    )
    fp.add_argument(
        "--camera",
        type=Path,
        default=None,
        metavar="CAM.toml",
        help="camera calibration (default: the photos' EXIF focal length, refined)",
    )
    fp.add_argument("--out", type=Path, required=True, metavar="GEOMETRY.json")
    add_quiet(fp)
    fp.set_defaults(func=from_photos)
    cc = sub.add_parser(
        "calibrate-camera",
        help="a camera file (CAM.toml) from photos of a calibration board",
        description=plain(CALIBRATE_HELP),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    cc.add_argument(
        "photos_dir", type=Path, metavar="BOARD_PHOTOS_DIR", help="folder of the board photos"
    )
    cc.add_argument("--board", type=Path, required=True, metavar="BOARD.toml", help="board file")
    cc.add_argument("--out", type=Path, required=True, metavar="CAM.toml")
    cc.add_argument(
        "--refine",
        action="store_true",
        help="let from-photos refine the intrinsics (default: held as calibrated)",
    )
    add_quiet(cc)
    cc.set_defaults(func=calibrate_camera)
    bp = sub.add_parser(
        "board",
        help="an image of the calibration board to print",
        description="Write the board of BOARD.toml as a PNG to print at --dpi (squares of "
        "square_m when printed at 100 %); measure the printed squares and markers and state "
        "them in the board file.",
    )
    bp.add_argument("board", type=Path, metavar="BOARD.toml")
    bp.add_argument("--out", type=Path, required=True, metavar="BOARD.png")
    bp.add_argument("--dpi", type=float, default=300.0, help="printer resolution (default 300)")
    bp.set_defaults(func=board_image)


def from_photos(args: argparse.Namespace) -> int:
    from dimacq.errors import SetupError
    from dimacq.io.setup_file import load_setup
    from dimacq.io.tags_file import load_tags
    from dimacq.services.geometry.photo_geometry import geometry_from_photos, load_camera

    say = (lambda _m: None) if args.quiet else (lambda m: print(m, flush=True))
    tags_path = args.tags
    if tags_path is None:
        for cand in (args.photos_dir / "tags.toml", args.photos_dir.parent / "tags.toml"):
            if cand.exists():
                tags_path = cand
                break
        else:
            raise SetupError(
                f"no tags file: give --tags TAGS.toml (none at {args.photos_dir / 'tags.toml'})"
            )
    setup = load_setup(args.setup)
    tags = load_tags(tags_path)
    camera = load_camera(args.camera) if args.camera else None
    res = geometry_from_photos(args.photos_dir, tags, setup=setup, camera=camera, progress=say)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(res.to_json(), indent=2) + "\n", encoding="utf-8")
    for issue in res.issues:
        say(f"  {issue.severity}: {issue}")
    b = res.bundle
    print(
        f"{len(res.orientations)} triaxes, {len(res.lines_of_action)} inputs from "
        f"{len(res.used)} of {len(res.photos)} photos; reprojection σ {b.sigma_px:.3f} px; "
        f"verdict {res.verdict}; written to {args.out}"
    )
    for u in res.unfixed:
        print(f"not fixed: {u}")
    return 2 if res.unfixed else 0


def calibrate_camera(args: argparse.Namespace) -> int:
    from dimacq.io.board_file import load_board
    from dimacq.services.geometry.camera_calibration import (
        STD_NAMES,
        calibrate_camera,
        write_camera_file,
    )

    say = (lambda _m: None) if args.quiet else (lambda m: print(m, flush=True))
    board = load_board(args.board)
    cal = calibrate_camera(args.photos_dir, board, progress=say)
    for issue in cal.issues:
        print(f"  {issue.severity}: {issue}")
    print(f"{len(cal.used)} of {len(cal.photos)} photos used")
    if cal.intrinsics is not None:
        c = cal.intrinsics
        tilts = [v.tilt_deg for v in cal.used]
        print(
            f"reprojection RMS {cal.rms_px:.3f} px; board tilts {min(tilts):.0f}–{max(tilts):.0f}°; "
            f"corners over {100 * cal.cover.cells:.0f} % of the image, reaching "
            f"{100 * cal.cover.reach:.0f} % of the way to its corners; the image's corners "
            f"placed to ±{cal.edge_std_px:.2f} px (1σ)"
        )
        for n in STD_NAMES:
            unit = " px" if n in ("fx", "fy", "cx", "cy") else ""
            print(f"  {n:>2} = {getattr(c, n):.6g} ± {cal.std[n]:.2g}{unit} (1σ)")
    if cal.refused:
        for r in cal.refused:
            print(f"refused: {r}")
        print(f"camera not calibrated; {args.out} not written")
        return 2
    write_camera_file(cal, board, args.out, refine=args.refine)
    print(f"camera written to {args.out} (refine = {str(args.refine).lower()})")
    return 0


def board_image(args: argparse.Namespace) -> int:
    from dimacq.io.board_file import load_board
    from dimacq.services.geometry.camera_calibration import write_board_print

    board = load_board(args.board)
    p = write_board_print(board, args.out, args.dpi)
    w_mm = 1000 * board.squares_x * board.square_m
    h_mm = 1000 * board.squares_y * board.square_m
    print(f"board {w_mm:.0f} x {h_mm:.0f} mm (without its margin) written to {p}; print at 100 %")
    return 0
