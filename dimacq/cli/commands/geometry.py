"""``dimacq geometry``: the test's geometry from photographs.

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
