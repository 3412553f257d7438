"""The sample data shipped with the package (`jaxpose/data/`, licences in its README):
OpenCV's chessboard photographs and their calibration, and OpenCV's cookie-box
photograph with the box's mesh and textured model."""

from __future__ import annotations

from pathlib import Path

__all__ = ["SAMPLES", "sample_path"]

#: The folder of the sample data.
SAMPLES = Path(__file__).resolve().parents[1] / "data"


def sample_path(*parts: str) -> Path:
    """The path of a sample file or folder, e.g. `sample_path("opencv_pose_box",
    "box.ply")`, `sample_path("chessboard")`.

    - `opencv_pose_box/`: `resized_IMG_3875.JPG` (a 718 x 480 photograph of a cookie
      box), `box.ply` (its mesh, cm), `cookies_ORB.yml.gz` (OpenCV's textured model of
      it), `corners.csv` (its corners measured on the photograph); the camera: fx =
      1384.484, fy = 1385.235, cx = 359, cy = 240, no distortion. `box.mp4`: OpenCV's
      tutorial video of the box (640 x 480, 455 frames), `box_video_camera.yml` the
      camera that tutorial assumes for it (approximate).
    - `chessboard/`: `left01.jpg` ... `left14.jpg` (640 x 480, a 9 x 6 board of 25 mm
      squares) and `left_intrinsics.yml` (OpenCV's calibration of that camera).

    **Raises:** `ValueError` naming the path when it is not there."""
    path = SAMPLES.joinpath(*parts)
    if not path.exists():
        raise ValueError(f"no sample {'/'.join(parts)!r} in {SAMPLES}")
    return path
