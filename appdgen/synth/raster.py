"""Drawing a 3-D scene into an ideal pinhole image with cv2: clipping, projection, (mip-mapped) textures."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from appdgen.synth.textures import MIP_SIGMAS

#: Fixed-point bits cv2 drawing gets: sub-pixel vertex positions for anti-aliased edges.
SHIFT = 4
NEAR = 0.3  # metres: closer geometry is clipped away

SMALL = 400  # pixels: textured polygons with a smaller bounding box are filled flat


@dataclass(frozen=True)
class Camera:
    """Pose: world → camera rotation R and camera centre C (metres); camera axes x right, y down, z forward."""

    R: np.ndarray
    C: np.ndarray


@dataclass(frozen=True)
class Texture:
    """A tiling gain map (float32 ≈ 1, mip levels) on a plane: texel (i, j) at origin + (j·e1 + i·e2) / texels_per_m."""

    levels: tuple[np.ndarray, ...]
    origin: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    texels_per_m: float


class Canvas:
    """An ideal pinhole BGR image (uint8) of `size` (w, h) with camera matrix K (pixels), drawn far to near."""

    def __init__(self, K: np.ndarray, size: tuple[int, int], camera: Camera, margin: float = 2.0):
        self.K, self.camera = np.asarray(K, dtype=np.float64), camera
        self.image = np.zeros((size[1], size[0], 3), np.uint8)
        self.planes = self._frustum(margin)

    def _frustum(self, margin: float) -> np.ndarray:
        """Half-spaces n·p + d ≥ 0 (camera frame): what projects into the canvas (± margin pixels), and z ≥ NEAR."""
        (fx, _, cx), (_, fy, cy) = self.K[:2]
        h, w = self.image.shape[:2]
        x0, x1 = (-0.5 - margin - cx) / fx, (w - 0.5 + margin - cx) / fx
        y0, y1 = (-0.5 - margin - cy) / fy, (h - 0.5 + margin - cy) / fy
        return np.array([[1, 0, -x0, 0], [-1, 0, x1, 0], [0, 1, -y0, 0], [0, -1, y1, 0], [0, 0, 1, -NEAR]])

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """World points (…, 3), metres → camera frame."""
        return (np.asarray(points, dtype=np.float64) - self.camera.C) @ self.camera.R.T

    def may_see(self, box: np.ndarray) -> bool:
        """False when a world box (2, 3) of min and max corners lies wholly outside one frustum half-space."""
        corners = np.array(np.meshgrid(*box.T, indexing="ij")).reshape(3, -1).T
        s = self.to_camera(corners) @ self.planes[:, :3].T + self.planes[:, 3]
        return not np.any(np.all(s < 0, axis=0))

    def clip_polygon(self, cam_points: np.ndarray) -> np.ndarray:
        """Sutherland–Hodgman against every frustum half-space; may return fewer than 3 points."""
        poly = cam_points
        for plane in self.planes:
            s = poly @ plane[:3] + plane[3]
            if np.all(s >= 0):
                continue
            if len(poly) < 3 or np.all(s < 0):
                return poly[:0]
            out = []
            for i in range(len(poly)):
                j = (i + 1) % len(poly)
                if s[i] >= 0:
                    out.append(poly[i])
                if (s[i] >= 0) != (s[j] >= 0):
                    out.append(poly[i] + (poly[j] - poly[i]) * (s[i] / (s[i] - s[j])))
            poly = np.array(out)
        return poly

    def clip_segment(self, cam_points: np.ndarray) -> np.ndarray:
        """The part of a segment (2, 3) inside the frustum; no points if none."""
        a, b = cam_points
        t0, t1 = 0.0, 1.0
        for plane in self.planes:
            sa, sb = a @ plane[:3] + plane[3], b @ plane[:3] + plane[3]
            if sa < 0 and sb < 0:
                return cam_points[:0]
            if sa < 0:
                t0 = max(t0, sa / (sa - sb))
            elif sb < 0:
                t1 = min(t1, sa / (sa - sb))
        return cam_points[:0] if t0 >= t1 else np.array([a + (b - a) * t0, a + (b - a) * t1])

    def _fixed(self, pixels: np.ndarray) -> np.ndarray:
        """Pixels → cv2's fixed-point int32 vertices."""
        return np.round(pixels * (1 << SHIFT)).astype(np.int32)

    def _visible(self, cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For shapes (M, N, 3) in the camera frame: which lie wholly inside the frustum, which need clipping."""
        s = cam @ self.planes[:, :3].T + self.planes[:, 3]  # (M, N, planes)
        inside = np.all(s >= 0, axis=(1, 2))
        outside = np.any(np.all(s < 0, axis=1), axis=1)
        return inside, ~inside & ~outside

    def fill(self, points: np.ndarray, color: np.ndarray, texture: Texture | None = None) -> None:
        """Fill a planar convex world polygon (N, 3) with a BGR colour, modulated by a texture if given."""
        if texture is None:
            self.fill_many(np.asarray(points)[None], color)
            return
        poly = self.clip_polygon(self.to_camera(points))
        if len(poly) >= 3:
            self._fill_textured(self._project(poly), _bgr(color), texture)

    def fill_many(self, polygons: np.ndarray, color: np.ndarray) -> None:
        """Fill non-overlapping convex world polygons (M, N, 3) with one colour, in one cv2 call."""
        shapes = self._shapes(polygons, self.clip_polygon, 3)
        if shapes:
            cv2.fillPoly(self.image, shapes, _bgr(color), cv2.LINE_AA, SHIFT)

    def lines(self, segments: np.ndarray, color: np.ndarray, thickness: int = 1) -> None:
        """Draw world segments (M, 2, 3) anti-aliased, `thickness` pixels wide, in one cv2 call."""
        shapes = self._shapes(segments, self.clip_segment, 2)
        if shapes:
            cv2.polylines(self.image, shapes, False, _bgr(color), thickness, cv2.LINE_AA, SHIFT)

    def _shapes(self, world: np.ndarray, clip: Callable[[np.ndarray], np.ndarray], least: int) -> list[np.ndarray]:
        """World shapes (M, N, 3) → cv2 fixed-point pixel vertices, clipping only those that cross the frustum."""
        if len(world) == 0:
            return []
        cam = self.to_camera(world)
        inside, partly = self._visible(cam)
        shapes = list(self._fixed(self._project(cam[inside])))
        for shape in cam[partly]:
            clipped = clip(shape)
            if len(clipped) >= least:
                shapes.append(self._fixed(self._project(clipped)))
        return shapes

    def _project(self, cam: np.ndarray) -> np.ndarray:
        """Camera-frame points (…, 3), z > 0 → canvas pixels (…, 2)."""
        p = cam @ self.K.T
        return p[..., :2] / p[..., 2:]

    def _fill_textured(self, px: np.ndarray, color: tuple[float, ...], texture: Texture) -> None:
        """Paint colour × the texture's gain inside the projected polygon px (pixels)."""
        h, w = self.image.shape[:2]
        x0, y0 = np.maximum(np.floor(px.min(axis=0)).astype(int) - 1, 0)
        x1, y1 = np.minimum(np.ceil(px.max(axis=0)).astype(int) + 2, (w, h))
        if (x1 - x0) * (y1 - y0) < SMALL:  # too few pixels for texture to show: flat mean colour, much cheaper
            mean = float(texture.levels[-1][0, 0])
            cv2.fillPoly(self.image, [self._fixed(px)], _bgr(np.multiply(color, mean)), cv2.LINE_AA, SHIFT)
            return
        H = np.array([[1.0, 0, -x0], [0, 1, -y0], [0, 0, 1]]) @ self._texel_to_pixel(texture)
        gain = self._mip_gain(texture, H, (x1 - x0, y1 - y0))
        paint = cv2.convertScaleAbs(cv2.transform(gain[..., None], np.array([color], np.float32).T))
        mask = np.zeros(gain.shape, np.uint8)
        cv2.fillPoly(mask, [self._fixed(px - (x0, y0))], 255, cv2.LINE_AA, SHIFT)
        alpha = mask.astype(np.float32) * np.float32(1 / 255)
        region = self.image[y0:y1, x0:x1]
        region[...] = cv2.blendLinear(paint, region, alpha, 1.0 - alpha)

    def _texel_to_pixel(self, texture: Texture) -> np.ndarray:
        """Homography from texel (column, row) coordinates to canvas pixels."""
        R, C = self.camera.R, self.camera.C
        plane = np.column_stack([R @ texture.e1, R @ texture.e2, R @ (texture.origin - C)])
        return self.K @ plane @ np.diag([1.0 / texture.texels_per_m, 1.0 / texture.texels_per_m, 1.0])

    def _mip_gain(self, texture: Texture, H: np.ndarray, size: tuple[int, int]) -> np.ndarray:
        """The gain map warped into a patch, each pixel from the mip level matching its footprint (texels/pixel)."""
        G = np.linalg.inv(H)
        u, v = np.arange(size[0], dtype=np.float32), np.arange(size[1], dtype=np.float32)
        wz = np.abs(np.float32(G[2, 0]) * u[None, :] + np.float32(G[2, 1]) * v[:, None] + np.float32(G[2, 2]))
        # |det J| of pixel → texel is |det G| / w³; its square root is the texels one pixel covers.
        sigma = np.float32(0.5 * np.sqrt(abs(np.linalg.det(G)))) / np.maximum(wz, 1e-12) ** 1.5
        sigma = np.clip(sigma, 0.0, MIP_SIGMAS[-1])
        level = np.where(sigma < 1.0, sigma, 1.0 + np.log2(np.maximum(sigma, 1.0)))  # MIP_SIGMAS[i] = 2^(i-1), i ≥ 1
        gain = np.zeros(size[::-1], np.float32)
        for i in range(int(level.min()), int(np.ceil(level.max())) + 1):
            weight = np.clip(1.0 - np.abs(level - i), 0.0, 1.0)
            # Warp only the rows and columns where this level counts: far less than the whole patch per level.
            rows, cols = np.flatnonzero(weight.any(axis=1)), np.flatnonzero(weight.any(axis=0))
            if rows.size == 0:
                continue
            (r0, r1), (c0, c1) = (rows[0], rows[-1] + 1), (cols[0], cols[-1] + 1)
            shift = np.array([[1.0, 0, -c0], [0, 1, -r0], [0, 0, 1]])
            warped = cv2.warpPerspective(
                texture.levels[i], shift @ H, (c1 - c0, r1 - r0), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP
            )
            gain[r0:r1, c0:c1] += weight[r0:r1, c0:c1] * warped
        return gain

    def discs(self, centers: np.ndarray, radii: np.ndarray, color: np.ndarray) -> None:
        """Draw spheres (world centres (M, 3), radii (M,), metres) as filled discs of their projected radius."""
        cam, radii = self.to_camera(centers), np.asarray(radii, dtype=np.float64)
        # A disc counts while any of it can reach the canvas: its centre within one radius of every side plane.
        reach = radii[:, None] * np.linalg.norm(self.planes[:, :3], axis=1)
        seen = np.all(cam @ self.planes[:, :3].T + self.planes[:, 3] >= -reach, axis=1) & (cam[:, 2] > NEAR)
        pixels = self._fixed(self._project(cam[seen]))
        radii = np.round(radii[seen] * self.K[0, 0] / cam[seen, 2] * (1 << SHIFT)).astype(int)
        for (x, y), r in zip(pixels, radii, strict=True):
            cv2.circle(self.image, (int(x), int(y)), int(r), _bgr(color), -1, cv2.LINE_AA, SHIFT)

    def sky(self, zenith: np.ndarray, horizon: np.ndarray, step: int = 9) -> None:
        """Fill with a sky gradient by elevation angle: horizon colour at 0°, zenith colour at ≥ 45°."""
        h, w = self.image.shape[:2]
        u, v = np.meshgrid(np.arange(0, w + step, step, dtype=np.float64),
                           np.arange(0, h + step, step, dtype=np.float64))
        rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(self.K).T @ self.camera.R  # world directions
        elevation = -rays[..., 1] / np.linalg.norm(rays, axis=-1)  # world y points down
        t = np.clip(elevation / np.sin(np.pi / 4), 0.0, 1.0)[..., None] ** 0.6
        coarse = (horizon + t * (zenith - horizon)).astype(np.float32)
        # Enlarging by `step` puts coarse sample i (taken at pixel i·step) at i·step + (step − 1)/2: an odd step
        # makes that offset whole, so the smooth gradient lands on the right pixels.
        big = cv2.resize(coarse, (coarse.shape[1] * step, coarse.shape[0] * step), interpolation=cv2.INTER_LINEAR)
        off = (step - 1) // 2
        self.image[...] = np.clip(big[off : off + h, off : off + w], 0, 255).astype(np.uint8)


def _bgr(color: np.ndarray) -> tuple[float, float, float]:
    """A colour as the float triple cv2 wants, clipped to 0…255."""
    b, g, r = np.clip(np.asarray(color, dtype=np.float64), 0, 255)
    return (float(b), float(g), float(r))
