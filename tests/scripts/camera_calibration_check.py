"""Board calibration against the simulated camera's truth, over several seeds.

For each seed, render ``--photos`` ChArUco board photos (8 × 11 squares of 25 mm, DICT_5X5_100,
tilts 20–45°, JPEG without EXIF) through the simulated camera, calibrate them with
:func:`dimacq.services.geometry.camera_calibration.calibrate_camera` (which reads only the
images) and compare with the truth: each intrinsic's error over its stated 1σ (``z``), the
largest distance between where the calibrated and the true camera image the same ray over the
whole image, the stated 1σ of the image's corners, the RMS reprojection error and the
verdict. Then the same with the board held
square-on (tilts 0–3°, which must be refused for its focal length) and with a chessboard.

    python tests/scripts/camera_calibration_check.py [--seeds 8] [--photos 15] [--phone]

``--phone`` uses the 12 MP phone camera (4000 × 3000 px) instead of the 2 MP machine-vision
camera. The figures go to ``camera_calibration_check_results.md`` beside this script
(``--results`` elsewhere) with the command, date, commit and machine load.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _results import Results, add_results_argument

from dimacq.io.board_file import BoardFile
from dimacq.pipeline.photogrammetry.calibration import image_difference_px
from dimacq.pipeline.photogrammetry.camera import Intrinsics
from dimacq.services.geometry.camera_calibration import STD_NAMES, calibrate_camera
from dimacq.simulators.camera.board import photograph_board
from dimacq.simulators.camera.render import PHONE_12MP, CameraModel

CHARUCO = BoardFile(
    squares_x=8, squares_y=11, square_m=0.025, marker_m=0.018, dictionary="DICT_5X5_100"
)
CHESS = BoardFile(type="chessboard", squares_x=10, squares_y=7, square_m=0.03)


def _truth(cam: CameraModel) -> Intrinsics:
    return Intrinsics(
        cam.f_px, cam.f_px, cam.cx, cam.cy, *cam.dist, width=cam.width, height=cam.height
    )


def _run(board: BoardFile, cam: CameraModel, n: int, seed: int, **kw: object) -> list[object]:
    with tempfile.TemporaryDirectory() as d:
        photograph_board(board, d, n, seed, cam, **kw)  # type: ignore[arg-type]
        cal = calibrate_camera(d, board)
    true = _truth(cam)
    c = cal.intrinsics
    if c is None:
        return [
            seed,
            board.type,
            "—",
            "—",
            "—",
            "—",
            "—",
            "—",
            "—",
            cal.verdict,
            "; ".join(cal.refused),
        ]
    z = {k: (getattr(c, k) - getattr(true, k)) / cal.std[k] for k in STD_NAMES}
    return [
        seed,
        board.type,
        f"{c.fx - true.fx:+.2f} ± {cal.std['fx']:.2f}",
        f"{c.cx - true.cx:+.2f} ± {cal.std['cx']:.2f}",
        f"{c.cy - true.cy:+.2f} ± {cal.std['cy']:.2f}",
        f"{max(abs(v) for v in z.values()):.2f}",
        f"{image_difference_px(true, c):.2f}",
        f"{cal.edge_std_px:.2f}",
        f"{cal.rms_px:.3f}",
        cal.verdict,
        " | ".join(r.split(":")[0].split(", so ")[0] for r in cal.refused),
        z,
    ]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--photos", type=int, default=15)
    ap.add_argument("--phone", action="store_true")
    add_results_argument(ap, __file__)
    args = ap.parse_args()
    cam = PHONE_12MP if args.phone else CameraModel()
    res = Results(__file__, "Board calibration against the simulated camera", args.results)
    res.note(f"camera {cam.width} x {cam.height} px, f {cam.f_px} px, {args.photos} photos a set")
    header = [
        "seed",
        "board",
        "fx err ± 1σ px",
        "cx err ± 1σ px",
        "cy err ± 1σ px",
        "max |z|",
        "image diff px",
        "corners 1σ px",
        "RMS px",
        "verdict",
        "refused",
    ]
    rows, zs = [], []
    for seed in range(args.seeds):
        r = _run(CHARUCO, cam, args.photos, seed)
        if len(r) > len(header):
            zs.append(r.pop())
        rows.append(r)
        print(r, flush=True)
    for seed in range(2):
        r = _run(CHARUCO, cam, args.photos, 100 + seed, tilt_deg=(0.0, 3.0))
        rows.append(r[: len(header)])
        print(rows[-1], flush=True)
    r = _run(CHESS, cam, args.photos, 200, fill=(0.6, 0.9))
    rows.append(r[: len(header)])
    res.table(header, rows, "Each set (the last three: square-on twice, a chessboard)")
    if zs:
        zz = np.array([[z[k] for k in STD_NAMES] for z in zs])
        res.table(
            ["intrinsic", "RMS z (1: the 1σ is right)", "largest |z|", "share within 3σ"],
            [
                [
                    k,
                    f"{np.sqrt(np.mean(zz[:, i] ** 2)):.2f}",
                    f"{np.max(np.abs(zz[:, i])):.2f}",
                    f"{np.mean(np.abs(zz[:, i]) <= 3):.2f}",
                ]
                for i, k in enumerate(STD_NAMES)
            ],
            f"Errors over the stated 1σ, the {len(zs)} tilted ChArUco sets",
        )
    res.write()
    print(res.text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
