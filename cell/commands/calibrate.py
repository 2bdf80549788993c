"""``cellctl calibrate-camera``: the camera's plane calibration from images of a board.

The board (circle grid or chessboard) lies on the work plane at a known place in the robot
base frame. ``--board FILE`` describes it in a small YAML file::

    kind: circles            # circles: a symmetric grid of dark dots on light paper
    cols: 11                 # dots per row (chessboard: inner corners per row), 3-100
    rows: 7                  # rows of dots (chessboard: inner corners per column), 3-100
    pitch_mm: 4.0            # circles: centre-to-centre distance (default 10)
    radius_mm: 1.0           # circles: dot radius (default 2.5)
    origin_mm: [230.0, 918.0]  # base-frame x, y of point (col 0, row 0) (default [0, 0])
    angle_deg: 0.0           # the board's col axis from the base x axis, counter-clockwise (default 0)

    kind: chessboard         # a chessboard instead: the points are its inner corners,
    cols: 9                  # the square at (-1, -1) is black, a one-square white border
    rows: 6
    square_mm: 10.0          # side of a square (default 10)
    origin_mm: [230.0, 918.0]
    angle_deg: 0.0

Point (col, row) lies at origin_mm + R(angle_deg) · (col, row) · pitch (or square). No
other key is accepted; a mistake in the file is named with its line and field
(``board.yaml:4: pitch: unknown field; did you mean 'pitch_mm'?``)
before any image is read. Images come from a folder (``--images DIR``, e.g. saved by the
camera vendor's tool) or from the configured camera (``--config deploy/cell.yaml --views
3``). The result is the JSON file the cell loads at start-up (``vision.calibration``),
written atomically; the command prints the reprojection error in pixels and mm.

The check: a calibration whose reprojection residual is far above the measurement noise
(over 2x and significant, see cell/calibration/check.py) is refused (exit 2, nothing
written), naming the views that disagree most. The noise is measured twice, apart from
the joint fit: each view fitted alone (with two or more views: a board bumped between
views, or a swapped or re-scaled image, shows here) and the circle detector's own centre
uncertainty. ``--accept-worse`` writes it anyway, with ``accept_worse: true`` and the
``warning`` in the file and, with ``--db``, a row in that cycle log's audit trail.
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from cell import paths
from cell.commands import file_in_the_way
from cell.errors import ConfigError
from cell.jsonsafe import json_safe


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate-camera", help="plane calibration of the camera from board images",
                       description=__doc__.replace("``", "").replace("::", ":"),
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--board", required=True, metavar="BOARD.yaml",
                   help="the board: kind, cols, rows, pitch_mm/radius_mm or square_mm, origin_mm, "
                        "angle_deg (format above)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--images", help="folder of board images")
    src.add_argument("--config", help="cell config: grab from its camera")
    p.add_argument("--views", type=int, default=3, help="frames to grab with --config (default 3)")
    p.add_argument("--u-axis-deg", type=float, default=0.0,
                   help="rough direction of the image +u axis in the base frame, ±45° (default 0)")
    p.add_argument("--no-distortion", action="store_true", help="fit a plain homography")
    p.add_argument("--out", required=True, help="calibration JSON to write")
    p.add_argument("--accept-worse", action="store_true",
                   help="write it even when its residual is far above the noise (warning in the file)")
    p.add_argument("--db", help="cycle log whose audit trail records the write (default: the "
                                "config's log.path with --config, else none)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from cell.vision import VisionError
    from cell.vision.board import load_board
    from cell.vision.calibration import calibrate
    board = load_board(args.board)
    out = _out_path(args.out)
    images = _images(args)
    try:
        cal = calibrate([(img, board) for _, img in images], distortion=not args.no_distortion,
                        u_axis_deg=args.u_axis_deg)
    except VisionError as exc:
        names = ", ".join(f"view {i} = {name}" for i, (name, _) in enumerate(images))
        raise ConfigError(f"calibration failed: {exc} ({names})") from None
    check = cal.check
    worst = ", ".join(f"view {v['view']} = {images[v['view']][0]} (rms {v['rms_px']:.3g} px)"
                      for v in check["views"][:2]) if len(images) > 1 else ""
    summary = (f"{len(images)} view(s), {cal.n_points} board points: reprojection rms {cal.rms_px:.4f} px "
               f"(max {cal.max_px:.4f}), rms {cal.rms_mm:.5f} mm")
    if not check["passed"]:
        failed = "; ".join(check["failures"]) + (f"; the views that disagree most: {worst}" if worst else "")
        if not args.accept_worse:
            print(f"{summary}\ncheck: FAILED: {failed}")
            raise ConfigError(f"calibration refused, nothing written: {failed} "
                              "(--accept-worse writes it anyway, with a warning)")
        warning = f"written with --accept-worse although its check failed: {failed}"
    else:
        warning = None
    doc = cal.as_dict() | {"accept_worse": warning is not None, "warning": warning}
    tmp = None
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = paths.temp_beside(out)
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump(json_safe(doc), f, indent=2, allow_nan=False)
        os.replace(tmp, out)
    except OSError as exc:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        raise ConfigError(f"--out {out}: cannot write the calibration: {exc.strerror or exc}") from None
    db = args.db or (_config_log(args.config) if args.config else None)
    if db:
        from cell.commands.robotcal import audit_calibration
        audit_calibration(db, "camera_calibration_write", out,
               warning or "written; check passed")
    print(f"{summary}; written to {out}")
    print(f"check: {check['reason']}: PASSED" if warning is None else f"WARNING: {warning}")
    return 0


def _config_log(config: str) -> str:
    """The cycle log of the cell config ``config`` (its audit trail)."""
    from cell.config import CellConfig
    return str(CellConfig.load(config).with_paths().log.path)


def _out_path(given: str) -> Path:
    """``--out`` as a path, refused before any work when it cannot be a file: a folder, or
    below something that is not one."""
    out = Path(given)
    if out.is_dir():
        raise ConfigError(f"--out {out}: is a folder; name the calibration file to write "
                          f"(e.g. {out / 'calibration.json'})")
    blocker = file_in_the_way(out)
    if blocker is not None:
        raise ConfigError(f"--out {out}: {blocker} is not a folder")
    return out


def _images(args) -> list[tuple[str, object]]:
    """(name, image) of every folder image, or of ``--views`` frames of the configured camera."""
    from drivers import camera as cameras
    if args.views < 1:
        raise ConfigError(f"--views {args.views} must be ≥ 1")
    if args.images:
        cam = cameras.create("folder", path=args.images)
    else:
        from cell.config import CellConfig
        cam = cameras.from_config(CellConfig.load(args.config).camera)
    out = []
    try:
        cam.open()
        n = cam.count if args.images else args.views
        for i in range(n):
            frame = cam.grab()
            out.append((frame.metadata.get("file", f"frame {i}"), frame.image))
    except Exception as exc:                       # noqa: BLE001 -- camera errors name the file
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(f"camera: {exc}") from None
    finally:
        try:
            cam.close()
        except Exception:                          # noqa: BLE001 -- already closed
            pass
    return out
