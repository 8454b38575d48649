"""Pinhole camera: intrinsics, projection and back-projection.

Camera frame convention (OpenCV): x right, y down, z forward (away from the camera), metres.
Image coordinates (u, v) are in pixels with (0, 0) at the centre of the top-left pixel.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float


class Intrinsics(eqx.Module):
    """Pinhole intrinsics of a depth (or colour) camera, no distortion.

    Use :meth:`Intrinsics.create` from Python numbers: it validates them. The image size is
    static (it fixes array shapes), the focal lengths and principal point are arrays.
    """

    fx: Float[Array, ""]
    """Focal length along u, pixels."""
    fy: Float[Array, ""]
    """Focal length along v, pixels."""
    cx: Float[Array, ""]
    """Principal point u, pixels."""
    cy: Float[Array, ""]
    """Principal point v, pixels."""
    width: int = eqx.field(static=True)
    """Image width W, pixels."""
    height: int = eqx.field(static=True)
    """Image height H, pixels."""

    @staticmethod
    def create(
        *, fx: float, fy: float, cx: float, cy: float, width: int, height: int
    ) -> Intrinsics:
        """Validated constructor from Python numbers.

        Raises:
            ValueError: naming the field and value when a value is non-finite or not physical
                (non-positive focal length or size, principal point outside the image).
        """
        for name, value in (("fx", fx), ("fy", fy), ("cx", cx), ("cy", cy)):
            value = float(value)
            if not math.isfinite(value):
                raise ValueError(f"Intrinsics: {name} must be finite, got {value!r}")
        for name, value in (("width", width), ("height", height)):
            if int(value) != value or int(value) <= 0:
                raise ValueError(f"Intrinsics: {name} must be a positive integer, got {value!r}")
        if fx <= 0 or fy <= 0:
            raise ValueError(f"Intrinsics: focal lengths must be positive, got fx={fx}, fy={fy}")
        if not (0 <= cx <= width) or not (0 <= cy <= height):
            raise ValueError(
                f"Intrinsics: principal point (cx={cx}, cy={cy}) lies outside the "
                f"{width}x{height} image"
            )
        return Intrinsics(
            fx=jnp.asarray(fx, dtype=float),
            fy=jnp.asarray(fy, dtype=float),
            cx=jnp.asarray(cx, dtype=float),
            cy=jnp.asarray(cy, dtype=float),
            width=int(width),
            height=int(height),
        )

    @property
    def shape(self) -> tuple[int, int]:
        """Image shape (H, W) as NumPy orders it."""
        return (self.height, self.width)

    def as_matrix(self) -> Float[Array, "3 3"]:
        """The 3x3 matrix K."""
        zero, one = jnp.zeros_like(self.fx), jnp.ones_like(self.fx)
        return jnp.array([[self.fx, zero, self.cx], [zero, self.fy, self.cy], [zero, zero, one]])

    def scaled(self, width: int, height: int) -> Intrinsics:
        """Intrinsics of the same camera resampled to a ``width`` x ``height`` image.

        Pixel centres are kept consistent: u' + 0.5 = (u + 0.5) * width / W.
        """
        sx = width / self.width
        sy = height / self.height
        return Intrinsics(
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
            width=int(width),
            height=int(height),
        )

    def to_dict(self) -> dict[str, float]:
        """Plain JSON-able dict ``{fx, fy, cx, cy, width, height}``."""
        return {
            "fx": float(self.fx),
            "fy": float(self.fy),
            "cx": float(self.cx),
            "cy": float(self.cy),
            "width": int(self.width),
            "height": int(self.height),
        }


def project(intrinsics: Intrinsics, points: Float[Array, "*batch 3"]) -> Float[Array, "*batch 2"]:
    """Project camera-frame points (metres) to pixels (u, v).

    Points at or behind the camera plane are clamped to z = 1 mm so the result stays finite;
    callers that care mask those points.
    """
    z = jnp.maximum(points[..., 2], 1e-3)
    u = intrinsics.fx * points[..., 0] / z + intrinsics.cx
    v = intrinsics.fy * points[..., 1] / z + intrinsics.cy
    return jnp.stack([u, v], axis=-1)


def project_host(intrinsics: Intrinsics, points: np.ndarray) -> np.ndarray:
    """:func:`project` in NumPy, for host-side bookkeeping (no device dispatch)."""
    fx, fy, cx, cy = (float(v) for v in (intrinsics.fx, intrinsics.fy, intrinsics.cx,
                                         intrinsics.cy))  # fmt: skip
    p = np.asarray(points, np.float64)
    z = np.maximum(p[..., 2], 1e-3)
    return np.stack([fx * p[..., 0] / z + cx, fy * p[..., 1] / z + cy], axis=-1)


def backproject(
    intrinsics: Intrinsics, uv: Float[Array, "*batch 2"], z: Float[Array, "*batch"]
) -> Float[Array, "*batch 3"]:
    """Back-project pixels (u, v) with depth ``z`` (metres, along the optical axis) to 3D."""
    x = (uv[..., 0] - intrinsics.cx) / intrinsics.fx * z
    y = (uv[..., 1] - intrinsics.cy) / intrinsics.fy * z
    return jnp.stack([x, y, z], axis=-1)


def pixel_rays(intrinsics: Intrinsics) -> Float[Array, "H W 3"]:
    """Per-pixel ray directions with z = 1 (so ``z * ray`` is the 3D point at depth z)."""
    u = jnp.arange(intrinsics.width, dtype=intrinsics.fx.dtype)
    v = jnp.arange(intrinsics.height, dtype=intrinsics.fx.dtype)
    uu, vv = jnp.meshgrid(u, v)
    x = (uu - intrinsics.cx) / intrinsics.fx
    y = (vv - intrinsics.cy) / intrinsics.fy
    return jnp.stack([x, y, jnp.ones_like(x)], axis=-1)


def pixel_rays_np(
    *, fx: float, fy: float, cx: float, cy: float, width: int, height: int
) -> np.ndarray:
    """NumPy twin of :func:`pixel_rays` for host-side code (generators, file tools)."""
    uu, vv = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    return np.stack([(uu - cx) / fx, (vv - cy) / fy, np.ones_like(uu)], axis=-1)
