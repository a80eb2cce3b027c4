"""Camera tools of ``acquire``: calibrate a camera from ChArUco views, print a marker or board at true scale.

Their options and help: acquire/commands/camera_options.py.
"""

from __future__ import annotations

import argparse
import glob
import io
import os
import struct
import sys
import time
import zlib
from pathlib import Path

import numpy as np

from acquire.commands.camera_options import calibrate_parser, print_parser
from common.errors import install_hint
from common.outputs import check_outputs, commit_file, write_output
from drivers.camera.intrinsics import CameraIntrinsics, write_intrinsics
from drivers.camera.targets import Target, charuco_board, dictionary_id, grid_board, single_marker
from drivers.errors import DriverError

DROP_FACTOR = 3.0  # a view whose RMS exceeds this multiple of the median is dropped


class CameraToolError(Exception):
    """Bad input or data for a camera tool: one line, exit code 2."""


def calibrate_main(argv: list[str]) -> int:
    p = calibrate_parser()
    args = p.parse_args(argv)
    inputs = sorted(glob.glob(args.images)) if args.images is not None else []
    check_outputs(inputs, [("--out", args.out)], args.force)
    if (args.images is None) == (args.live is None):
        raise CameraToolError("give a folder or glob of images, or --live CAMERA (one of them)")
    if not all(v and v > 0 for v in (args.cols, args.rows, args.square, args.size)):
        raise CameraToolError("the ChArUco board needs --cols, --rows, --square and --size, all > 0")
    target = _charuco(args)
    images = _live_images(args.live, args.views) if args.live is not None else _folder_images(args.images)
    result = calibrate(images, target, args.min_corners)
    temp = args.out.with_name(f".{args.out.stem}.{os.getpid()}.tmp{args.out.suffix}")  # FileStorage wants a name
    try:
        write_intrinsics(temp, result.camera, avg_reprojection_error=result.rms,
                         calibration_time=time.strftime("%Y-%m-%d %H:%M:%S"))
        with open(temp, "rb+") as fh:
            os.fsync(fh.fileno())
        commit_file(temp, args.out, args.force)  # whole or not at all
    finally:
        temp.unlink(missing_ok=True)
    k = result.camera.matrix
    print(f"{result.used} of {len(images)} views used ({result.skipped} without enough corners, "
          f"{result.dropped} dropped as outliers); RMS reprojection error {result.rms:.3f} px")
    sd = result.std
    print(f"fx {k[0, 0]:.2f} ± {sd[0]:.2f}  fy {k[1, 1]:.2f} ± {sd[1]:.2f}  cx {k[0, 2]:.2f} ± {sd[2]:.2f}  "
          f"cy {k[1, 2]:.2f} ± {sd[3]:.2f} px; distortion "
          + " ".join(f"{v:.5g} ± {e:.2g}" for v, e in zip(result.camera.distortion, sd[4:], strict=False)))
    print(f"wrote {args.out}")
    return 0


class Calibration:
    """A calibration's outcome: ``camera``, ``rms`` (px), views ``used``, ``skipped`` and ``dropped``,
    ``per_view`` RMS (px) of the used views, and ``std``: the standard uncertainty of fx, fy, cx, cy (px) and
    of the distortion coefficients k1, k2, p1, p2, k3, as OpenCV's calibrateCameraExtended estimates them
    from the residuals."""

    def __init__(self, camera: CameraIntrinsics, rms: float, used: int, skipped: int, dropped: int,
                 per_view: np.ndarray, std: np.ndarray) -> None:
        self.camera, self.rms, self.used, self.skipped, self.dropped = camera, rms, used, skipped, dropped
        self.per_view, self.std = per_view, std


def calibrate(images: list[np.ndarray], target: Target, min_corners: int = 8) -> Calibration:
    """Intrinsics from ChArUco views (8-bit images of one size); CameraToolError if too few views are usable."""
    import cv2

    from drivers.camera.targets import Detector

    if not images:
        raise CameraToolError("no images to calibrate from")
    shape = images[0].shape[:2]
    if any(im.shape[:2] != shape for im in images):
        raise CameraToolError("the views differ in size; calibrate one camera resolution at a time")
    detector = Detector(target, "subpix")
    board = target.board
    objects, points, skipped = [], [], 0
    for image in images:
        obs = detector.detect(image)
        corners = np.asarray(board.getChessboardCorners(), dtype=np.float32)
        ids = np.asarray(obs.corner_ids, dtype=np.int32)
        if len(ids) < min_corners or board.checkCharucoCornersCollinear(ids.reshape(-1, 1)):
            skipped += 1
            continue
        objects.append(corners[ids].reshape(-1, 1, 3))
        points.append(obs.image_points.astype(np.float32).reshape(-1, 1, 2))
    if len(objects) < 4:
        raise CameraToolError(f"only {len(objects)} of {len(images)} views show the board well enough "
                              f"(>= {min_corners} corners, not in a line); at least 4 are needed")
    size = (shape[1], shape[0])

    def fit(objs: list, pts: list) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        rms, k, d, _, _, std, _, per_view = cv2.calibrateCameraExtended(objs, pts, size, None, None)
        return rms, k, d, np.asarray(per_view).reshape(-1), np.asarray(std, dtype=float).reshape(-1)[:9]

    rms, k, d, per_view, std = fit(objects, points)
    keep = per_view <= DROP_FACTOR * np.median(per_view)
    dropped = int((~keep).sum())
    if dropped and keep.sum() >= 4:
        objects = [o for o, ok in zip(objects, keep, strict=True) if ok]
        points = [q for q, ok in zip(points, keep, strict=True) if ok]
        rms, k, d, per_view, std = fit(objects, points)
    else:
        dropped = 0
    return Calibration(CameraIntrinsics(k, d.reshape(-1), size[0], size[1]), float(rms), len(objects), skipped,
                       dropped, per_view, std)


def _charuco(args: argparse.Namespace) -> Target:
    try:
        return charuco_board(args.cols, args.rows, args.square, args.size, dictionary_id(args.dict), args.first)
    except ValueError as exc:
        raise CameraToolError(str(exc)) from None


def _folder_images(pattern: str) -> list[np.ndarray]:
    from drivers.camera.sources import ImageReplay

    source = ImageReplay(pattern)
    source.open(1.0)
    return [source.grab(1.0)[0] for _ in source.files]


def _live_images(camera: str, views: int) -> list[np.ndarray]:
    from drivers.camera.sources import LiveCamera

    source = LiveCamera(int(camera) if camera.isdigit() else camera)
    source.open(5.0)
    images = []
    try:
        for k in range(views):
            print(f"view {k + 1}/{views}: hold the board still, in a new position", file=sys.stderr)
            time.sleep(1.0)
            images.append(source.grab(5.0)[0])
    finally:
        source.close()
    return images


def print_main(argv: list[str]) -> int:
    p = print_parser()
    args = p.parse_args(argv)
    target = _print_target(args)
    if not 72 <= args.dpi <= 4800:
        raise CameraToolError(f"--dpi {args.dpi} must be between 72 and 4800")
    suffix = args.out.suffix.lower()
    if suffix not in (".png", ".pdf"):
        raise CameraToolError(f"--out {args.out}: write .png or .pdf")
    check_outputs([], [("--out", args.out)], args.force)
    ppm = args.dpi / 0.0254
    margin = round(0.01 * ppm)  # 10 mm white quiet zone
    image, _ = target.texture(ppm, margin)
    w, h = target.extent
    write_output(args.out, (png if suffix == ".png" else pdf)(args.out, image, args.dpi), args.force)
    print(f"wrote {args.out}: {target.kind} {w * 1e3:.1f} x {h * 1e3:.1f} mm (+10 mm margin) at {args.dpi} dpi; "
          "print at 100 % (actual size) and measure the result")
    return 0


def _print_target(args: argparse.Namespace) -> Target:
    try:
        dictionary = dictionary_id(args.dict)
        if (args.marker is None) == (args.board is None):
            raise CameraToolError("give --marker ID or --board grid|charuco")
        if not args.size or args.size <= 0:
            raise CameraToolError("--size (the marker side) is required and must be > 0")
        if args.marker is not None:
            return single_marker(args.marker, args.size, dictionary)
        if not (args.cols and args.rows and args.cols > 0 and args.rows > 0):
            raise CameraToolError(f"--board {args.board} needs --cols and --rows")
        if args.board == "grid":
            return grid_board(args.cols, args.rows, args.size, args.gap or args.size / 5, dictionary, args.first)
        if not args.square:
            raise CameraToolError("--board charuco needs --square (m)")
        return charuco_board(args.cols, args.rows, args.square, args.size, dictionary, args.first)
    except ValueError as exc:
        raise CameraToolError(str(exc)) from None


def png(path: Path, image: np.ndarray, dpi: int) -> bytes:
    """8-bit image -> PNG bytes with a pHYs chunk (pixels per metre) so that viewers and printers know its scale;
    ``path`` names it in messages."""
    import cv2

    ok, data = cv2.imencode(".png", image)
    if not ok:
        raise CameraToolError(f"cannot encode {path}")
    raw = data.tobytes()
    ppm = round(dpi / 0.0254)
    body = b"pHYs" + struct.pack(">IIB", ppm, ppm, 1)
    chunk = struct.pack(">I", 9) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)
    end_of_ihdr = 8 + 8 + 13 + 4  # signature, IHDR length+type, IHDR data, CRC
    return raw[:end_of_ihdr] + chunk + raw[end_of_ihdr:]


def pdf(path: Path, image: np.ndarray, dpi: int) -> bytes:
    """8-bit image -> one-page PDF bytes whose page is the image at ``dpi`` (true scale when printed at 100 %)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise CameraToolError(f"PDF output needs matplotlib ({install_hint('report')}); write .png") from None
    h, w = image.shape[:2]
    fig = plt.figure(figsize=(w / dpi, h / dpi))
    ax = fig.add_axes((0, 0, 1, 1))
    ax.imshow(image, cmap="gray", vmin=0, vmax=255, interpolation="nearest")
    ax.set_axis_off()
    buffer = io.BytesIO()
    fig.savefig(buffer, dpi=dpi, format="pdf")
    plt.close(fig)
    return buffer.getvalue()


def main(argv: list[str]) -> int:
    """``argv[0]`` is the subcommand (calibrate-camera or print-board)."""
    try:
        if argv[0] == "calibrate-camera":
            return calibrate_main(argv[1:])
        return print_main(argv[1:])
    except (CameraToolError, DriverError, ValueError) as exc:
        print(f"acquire {argv[0]}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2

