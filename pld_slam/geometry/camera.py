"""The rectified stereo camera: intrinsics shared by both images and a horizontal baseline.

Frames: the left camera ``c`` has x right, y down, z forward; the right camera sits at
``(+baseline, 0, 0)`` in it with the same orientation. Pixels are ``(u, v)`` =
(column, row). A point at depth z has disparity ``d = u_left - u_right = fx * b / z``.

The images may measure ``d + disparity_offset`` instead: the offset is ``cx_left -
cx_right``, zero when both images were rectified to one principal point. The front end
removes it where it measures disparities (`image_disparity_to_metric`), so that every
later stage sees ``d = bf / z`` and right columns ``u_left - d``.
"""

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class StereoCamera:
    """A rectified stereo pair: pinhole intrinsics [px], baseline [m], image size [px], and the
    disparity [px] the images measure at infinite depth (module docstring)."""

    fx: float
    fy: float
    cx: float
    cy: float
    baseline: float
    width: int
    height: int
    disparity_offset: float = 0.0

    @property
    def K(self) -> np.ndarray:
        """The 3x3 intrinsic matrix of both rectified images."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)`` of both images [px]."""
        return self.width, self.height

    def scaled(self, factor: float) -> "StereoCamera":
        """The camera of its images resized by ``factor`` (e.g. 0.5 halves each side).

        The new size is the old one times ``factor``, rounded (at least 1 px); the
        intrinsics follow the resize that produces exactly that size, ``s_x = W' / W``
        and ``s_y = H' / H``, with pixel centres at integers: ``fx' = s_x fx`` and
        ``cx' = s_x (cx + 0.5) - 0.5`` (the same for y). The baseline is a length in the
        world and stays.
        """
        width, height = (max(1, round(side * factor)) for side in (self.width, self.height))
        s_x, s_y = width / self.width, height / self.height
        return StereoCamera(
            fx=self.fx * s_x,
            fy=self.fy * s_y,
            cx=s_x * (self.cx + 0.5) - 0.5,
            cy=s_y * (self.cy + 0.5) - 0.5,
            baseline=self.baseline,
            width=width,
            height=height,
            disparity_offset=s_x * self.disparity_offset,
        )

    @property
    def bf(self) -> float:
        """Baseline times focal length [m px]: disparity = bf / depth."""
        return self.baseline * self.fx

    def project(self, p_c: np.ndarray) -> np.ndarray:
        """Left-image pixels (N, 2) of points (N, 3) in the left camera frame."""
        z = p_c[:, 2]
        return np.column_stack(
            [self.fx * p_c[:, 0] / z + self.cx, self.fy * p_c[:, 1] / z + self.cy]
        )

    def inside_image(self, pixels: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
        """Whether pixels (N, 2) lie inside the image, at least ``margin_px`` from its border (N,) bool."""
        return (
            (pixels[:, 0] >= margin_px) & (pixels[:, 0] <= self.width - 1.0 - margin_px)
            & (pixels[:, 1] >= margin_px) & (pixels[:, 1] <= self.height - 1.0 - margin_px)
        )

    def project_stereo(self, p_c: np.ndarray) -> np.ndarray:
        """Stereo pixels ``(u_left, v, u_right)`` (N, 3) of points (N, 3) in the left camera."""
        uv = self.project(p_c)
        u_right = uv[:, 0] - self.bf / p_c[:, 2]
        return np.column_stack([uv, u_right])

    def backproject(self, uv: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Points (N, 3) in the left camera frame from left pixels (N, 2) and depths (N,)."""
        x = (uv[:, 0] - self.cx) / self.fx * depth
        y = (uv[:, 1] - self.cy) / self.fy * depth
        return np.column_stack([x, y, depth])

    def image_disparity_to_metric(self, image_disparity: np.ndarray) -> np.ndarray:
        """Disparities ``bf / z`` (N,) [px] of disparities (N,) measured between the two images."""
        return image_disparity - self.disparity_offset

    def triangulate(self, uv_left: np.ndarray, disparity: np.ndarray) -> np.ndarray:
        """Points (N, 3) in the left camera frame from left pixels (N, 2) and disparities (N,) [px]."""
        return self.backproject(uv_left, self.bf / disparity)
