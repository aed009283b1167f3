"""A random street seen from a car, as a 3-D scene of drawing operations for a pinhole Canvas.

World frame (metres): x right, y down, z along the street; the ground is y = 0, heights are −y.
Everything random is drawn here, before any canvas exists, so one scene renders identically into
canvases of any size: the distorted frame's large canvas and the ideal pinhole image alike.
"""
from __future__ import annotations

import colorsys
from dataclasses import dataclass, field

import numpy as np

from appdgen.synth import textures as _textures
from appdgen.synth.raster import Camera, Canvas, Texture

UP = np.array([0.0, -1.0, 0.0])
DOWN = -UP
ALONG = np.array([0.0, 0.0, 1.0])  # down the street
ACROSS = np.array([1.0, 0.0, 0.0])
FAR = 600.0  # metres: where the ground and road end

#: Per kind of district: building width and height ranges (m), odds of a gap, of a facade on the building
#: line (no setback) and of a shop front, and the wall styles.
DISTRICTS = {
    "downtown": dict(width=(8, 30), height=(10, 40), gap=0.1, flush=0.8, shop=0.7,
                     styles=["plaster", "blocks", "panels", "bricks"]),
    "residential": dict(width=(7, 18), height=(5, 13), gap=0.3, flush=0.3, shop=0.2,
                        styles=["plaster", "bricks", "planks"]),
    "industrial": dict(width=(15, 60), height=(4, 12), gap=0.25, flush=0.4, shop=0.0,
                       styles=["panels", "planks", "blocks", "bricks"]),
}


@dataclass(frozen=True)
class Mount:
    """How the camera sits on the car: height (m) and the spread of its pose from frame to frame.

    lateral: σ of the offset from the lane centre (m); height_jitter: ± around height (m); yaw: σ of the heading
    relative to the street, clipped at ± yaw_max; pitch, roll: ± bounds (rad); offset: a sideways move of the
    posed camera along its own x axis (m, + = right), made after every draw. Every draw is made whatever the
    values, so two mounts give the same street (buildings, light, texture) from two poses.
    """

    height: float
    height_jitter: float
    lateral: float
    yaw: float
    yaw_max: float
    pitch: float
    roll: float
    offset: float = 0.0


#: A camera bolted to a car driving down the street. Lane keeping holds the heading to within about a degree of
#: the lane (σ 0.01 rad = 0.6°, clipped at 0.03) and the car to ~0.3 m of the lane centre; suspension pitches the
#: body by about ±0.5° when braking or accelerating (±0.008 rad), rolls it by ±0.3° in gentle curves (±0.005 rad)
#: and compresses it by a few centimetres (±0.03 m around KITTI's 1.65 m). With KITTI camera 02 (fx 960 px) the
#: vanishing point moves by σ 10 px across and ±8 px up and down, the horizon tilts by ±3.5 px at the image edge:
#: less than a ±5 % principal-point error (±35 px in x, ±11 px in y), so the scene's geometry stays a cue to it.
CAR = Mount(height=1.65, height_jitter=0.03, lateral=0.3, yaw=0.01, yaw_max=0.03, pitch=0.008, roll=0.005)
#: A hand-held pose spread (a camera waved around: yaw σ 0.12 rad, pitch ±0.05, roll ±0.035): it moves
#: the vanishing point by σ 115 px across and ±48 px up and down at full size, hiding the principal point's cue.
LOOSE = Mount(height=1.75, height_jitter=0.35, lateral=0.3, yaw=0.12, yaw_max=0.3, pitch=0.05, roll=0.035)
#: Names for the command line.
MOUNTS = {"car": CAR, "loose": LOOSE}


#: A drawing operation: a Canvas method's name and its arguments, the first being world points (…, 3).
Op = tuple[str, tuple]


@dataclass
class Scene:
    """Camera pose, sky colours, and groups of drawing operations with their world bounding boxes, far to near."""

    camera: Camera
    zenith: np.ndarray
    horizon: np.ndarray
    groups: list[tuple[np.ndarray, list[Op]]] = field(default_factory=list)
    blur: float = 0.0  # raw pixels: lens softness
    noise: float = 0.0  # grey levels: sensor noise
    noise_seed: int = 0

    def draw(self, canvas: Canvas) -> None:
        """Paint the scene into a canvas built on self.camera."""
        canvas.sky(self.zenith, self.horizon)
        for box, ops in self.groups:
            if canvas.may_see(box):  # one test skips a whole building or pole out of view
                for name, args in ops:
                    getattr(canvas, name)(*args)


def _bounds(ops: list[Op]) -> np.ndarray:
    """World bounding box (2, 3) of a group of operations; discs are widened by their largest radius."""
    points = [np.reshape(args[0], (-1, 3)) for _, args in ops]
    pad = max((float(np.max(args[1], initial=0.0)) for name, args in ops if name == "discs"), default=0.0)
    stacked = np.concatenate(points)
    return np.stack([stacked.min(axis=0) - pad, stacked.max(axis=0) + pad])


def hsv(h: float, s: float, v: float) -> np.ndarray:
    """A BGR colour (0…255) from hue, saturation, value in 0…1."""
    r, g, b = colorsys.hsv_to_rgb(h % 1.0, s, v)
    return np.array([b, g, r]) * 255.0


def rects(origin: np.ndarray, along: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Upright rectangles on a wall: boxes (M, 4) of (s0, s1, h0, h1) metres along `along` and up → (M, 4, 3)."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    s = boxes[:, [0, 1, 1, 0]]
    h = boxes[:, [2, 2, 3, 3]]
    return origin + s[..., None] * along + h[..., None] * UP


def flat(x0: float, x1: float, z0: float, z1: np.ndarray | float, height: float = 0.0) -> np.ndarray:
    """Horizontal rectangles x0…x1 × z0…z1 (broadcast over z) at a height → (M, 4, 3)."""
    z0, z1 = np.broadcast_arrays(np.atleast_1d(z0), np.atleast_1d(z1))
    x0, x1 = np.broadcast_to(x0, z0.shape), np.broadcast_to(x1, z0.shape)
    xs = np.stack([x0, x1, x1, x0], 1)
    zs = np.stack([z0, z0, z1, z1], 1)
    return np.stack([xs, np.full_like(xs, -height), zs], -1)


class Street:
    """Draws one random street: layout, lighting, buildings, road furniture."""

    def __init__(self, rng: np.random.Generator, mount: "Mount"):
        self.rng, self.mount = rng, mount
        elevation, azimuth = rng.uniform(0.25, 1.1), rng.uniform(-np.pi, np.pi)
        flat_sun = np.cos(elevation)
        self.sun = np.array([flat_sun * np.sin(azimuth), -np.sin(elevation), flat_sun * np.cos(azimuth)])  # unit, up
        self.overcast = rng.random() < 0.3
        self.ambient = rng.uniform(0.7, 0.9) if self.overcast else rng.uniform(0.4, 0.65)
        self.exposure = rng.uniform(0.8, 1.15)
        lane = rng.uniform(2.8, 3.7)
        self.lane = lane
        self.lanes = (int(rng.integers(1, 3)), int(rng.integers(1, 3)))
        self.parking = (rng.random() < 0.5, rng.random() < 0.5)  # a parking strip outside the lanes, per side
        strip = rng.uniform(2.0, 2.5)
        # Road edges at x = −edge[0], +edge[1]; the driving lanes end at ±lanes·lane.
        self.edge = tuple(n * lane + strip * p for n, p in zip(self.lanes, self.parking, strict=False))
        self.walk = (rng.uniform(1.5, 5.0), rng.uniform(1.5, 5.0))
        self.curb = rng.uniform(0.08, 0.18)
        self.end = rng.uniform(90.0, 320.0) if rng.random() < 0.5 else None
        self.district = str(rng.choice(["downtown", "residential", "industrial"], p=[0.45, 0.35, 0.2]))
        self.camera = self._camera()
        self.ground: list[tuple[str, tuple]] = []
        self.back: list[list] = []  # groups of ops behind the building line: drawn before it
        self.buildings: list[tuple[float, list]] = []
        self.furniture: list[tuple[float, list]] = []

    def _camera(self) -> Camera:
        """The camera in a right-hand lane, posed by self.mount's jitter (metres, radians)."""
        rng, m = self.rng, self.mount
        x = (int(rng.integers(0, self.lanes[1])) + 0.5) * self.lane + rng.normal(0.0, m.lateral)
        C = np.array([x, -rng.uniform(m.height - m.height_jitter, m.height + m.height_jitter), 0.0])
        yaw = np.clip(rng.normal(0.0, m.yaw), -m.yaw_max, m.yaw_max)
        pitch, roll = rng.uniform(-m.pitch, m.pitch), rng.uniform(-m.roll, m.roll)
        cy, sy, cp, sp, cr, sr = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
        Ry = np.array([[cy, 0, -sy], [0, 1, 0], [sy, 0, cy]])
        Rx = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
        Rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
        return Camera(R=Rz @ Rx @ Ry, C=C)

    def lit(self, color: np.ndarray, normal: np.ndarray) -> np.ndarray:
        """A surface colour under this scene's sun and sky light."""
        # Lambert's law; self.sun points at the sun. Overcast: a dull, direction-free share.
        direct = 0.3 if self.overcast else max(0.0, float(np.dot(normal, self.sun)))
        return color * self.exposure * (self.ambient + (1.0 - self.ambient) * direct)

    def texture(self, kind: str, origin: np.ndarray, e1: np.ndarray, e2: np.ndarray = DOWN) -> Texture:
        """One of the pooled variants of a texture kind (see _textures.KINDS), at a random scale, laid on a plane."""
        levels = _textures.pooled(kind, int(self.rng.integers(_textures.POOL)))
        texels_per_m = _textures.KINDS[kind][1] * self.rng.uniform(0.8, 1.25)
        return Texture(levels, origin, e1, e2, texels_per_m)

    def build(self) -> Scene:
        """Generate everything and return the scene in painter's order."""
        rng = self.rng
        self.road()
        for side in (-1, 1):
            self.sidewalk(side)
            self.building_row(side)
            self.furniture_row(side)
        self.overhead()
        if self.end is not None:
            self.end_row()
        groups = [self.ground, *self.back]
        groups += [group for _, group in sorted(self.buildings, key=lambda kv: -kv[0])]
        groups += [group for _, group in sorted(self.furniture, key=lambda kv: -kv[0])]
        clear = hsv(rng.uniform(0.55, 0.62), rng.uniform(0.35, 0.7), rng.uniform(0.7, 0.95))
        grey = hsv(0.6, rng.uniform(0.0, 0.08), rng.uniform(0.6, 0.85))
        zenith = grey if self.overcast else clear
        horizon = zenith + (255.0 - zenith) * rng.uniform(0.4, 0.8)
        return Scene(
            self.camera, zenith * self.exposure, horizon * self.exposure, [(_bounds(g), g) for g in groups if g],
            blur=float(rng.uniform(0.0, 0.6)), noise=float(rng.uniform(0.5, 2.5)),
            noise_seed=int(rng.integers(2**62)),
        )

    # --- the ground: road, markings, sidewalks -------------------------------------------------

    def road(self) -> None:
        """Ground, asphalt, lane markings, a crosswalk and repair seams."""
        rng, (left, right) = self.rng, self.edge
        origin = np.array([self.camera.C[0], 0.0, 0.0])  # keeps texel coordinates small (cv2 warps use 16 bits)
        soil = hsv(rng.uniform(0.08, 0.3), rng.uniform(0.15, 0.45), rng.uniform(0.3, 0.55))
        self.surface(flat(-300, 300, -30, FAR)[0], soil, "grass", origin)
        tar = self.tar()
        self.surface(flat(-left, right, -30, FAR)[0], tar, "asphalt", origin)
        for _ in range(int(rng.integers(0, 6))):  # repair seams across the road: long near-horizontal lines
            z = rng.uniform(3.0, 60.0)
            seam = flat(-left, right, z, z + rng.uniform(0.04, 0.15))
            self.ground.append(("fill_many", (seam, self.lit(tar * rng.uniform(0.6, 1.3), UP))))
        self.markings()
        if rng.random() < 0.35:
            self.crosswalk(rng.uniform(6.0, 35.0))

    def surface(self, quad: np.ndarray, colour: np.ndarray, kind: str, origin: np.ndarray) -> None:
        """A textured horizontal ground quad (4, 3), texture rows running down the street."""
        self.ground.append(("fill", (quad, self.lit(colour, UP), self.texture(kind, origin, ACROSS, ALONG))))

    def tar(self) -> np.ndarray:
        """An asphalt colour: dark, nearly grey."""
        return hsv(self.rng.uniform(0.55, 0.65), self.rng.uniform(0.0, 0.1), self.rng.uniform(0.25, 0.5))

    def markings(self) -> None:
        """Centre, lane and edge lines: solid or dashed stripes converging on the vanishing point."""
        rng = self.rng
        paint = self.lit(hsv(0.0, 0.0, rng.uniform(0.75, 0.95)), UP)
        yellow = self.lit(hsv(0.13, 0.8, 0.9), UP)
        centre_kind = rng.choice(["dashed", "solid", "double"])
        self.stripe(0.0, yellow if centre_kind == "double" and rng.random() < 0.5 else paint, centre_kind)
        for i in range(1, self.lanes[1]):
            self.stripe(i * self.lane, paint, "dashed")
        for i in range(1, self.lanes[0]):
            self.stripe(-i * self.lane, paint, "dashed")
        if rng.random() < 0.7:
            self.stripe(-self.lanes[0] * self.lane + 0.3, paint, "solid")
            self.stripe(self.lanes[1] * self.lane - 0.3, paint, "solid")
        for side in (-1, 1):
            if self.parking[side > 0] and rng.random() < 0.6:  # parking bays: short lines across the strip
                a, b = sorted((side * self.lanes[side > 0] * self.lane, side * self.edge[side > 0]))
                z0 = np.arange(rng.uniform(-30.0, -24.0), 120.0, rng.uniform(5.0, 6.5))
                self.ground.append(("fill_many", (flat(a, b, z0, z0 + 0.12), paint)))

    def stripe(self, x: float, color: np.ndarray, kind: str) -> None:
        """One longitudinal road line at x: dashed, solid or double solid."""
        w = self.rng.uniform(0.1, 0.2)
        if kind == "dashed":
            dash = self.rng.choice([3.0, 4.5, 6.0])
            z0 = np.arange(-30.0 + self.rng.uniform(0, 3 * dash), FAR * 0.5, 3 * dash)
            self.ground.append(("fill_many", (flat(x - w / 2, x + w / 2, z0, z0 + dash), color)))
        elif kind == "solid":
            self.ground.append(("fill_many", (flat(x - w / 2, x + w / 2, -30, FAR * 0.5), color)))
        else:
            for dx in (-w, w):
                self.ground.append(("fill_many", (flat(x + dx - w / 2, x + dx + w / 2, -30, FAR * 0.5), color)))

    def crosswalk(self, z: float) -> None:
        """Zebra bars across the road at z and a stop line before them."""
        rng, (left, right) = self.rng, self.edge
        paint = self.lit(hsv(0.0, 0.0, rng.uniform(0.8, 0.95)), UP)
        width, depth = rng.uniform(0.4, 0.6), rng.uniform(3.0, 5.0)
        x0 = np.arange(-left + 0.3, right - 0.3 - width, 2 * width)
        bars = np.concatenate([flat(x, x + width, z, z + depth) for x in x0])
        self.ground.append(("fill_many", (bars, paint)))
        self.ground.append(("fill_many", (flat(0.0, right, z - 2.0, z - 2.0 + rng.uniform(0.3, 0.5)), paint)))

    def sidewalk(self, side: int) -> None:
        """Paved sidewalk, raised by the curb, with a curb face and a curb-stone strip along the road edge."""
        rng = self.rng
        edge, walk = self.edge[side > 0], self.walk[side > 0]
        inner, outer = side * edge, side * (edge + walk)
        slab = hsv(rng.uniform(0.0, 0.15), rng.uniform(0.0, 0.3), rng.uniform(0.45, 0.75))
        origin = np.array([inner, -self.curb, 0.0])
        self.surface(flat(min(inner, outer), max(inner, outer), -30, FAR, self.curb)[0], slab, "paving", origin)
        stone = hsv(0.1, 0.05, rng.uniform(0.6, 0.85))
        face = rects(np.array([inner, 0.0, -30.0]), ALONG, [0.0, FAR, 0.0, self.curb])
        self.ground.append(("fill_many", (face, self.lit(stone, ACROSS * -side))))
        strip = flat(min(inner, inner + side * 0.2), max(inner, inner + side * 0.2), -30, FAR, self.curb)
        self.ground.append(("fill_many", (strip, self.lit(stone * 1.05, UP))))

    # --- buildings -------------------------------------------------------------------------------

    def district_params(self) -> dict:
        """Building size ranges (metres), odds and wall styles for this street's kind of district."""
        return DISTRICTS[self.district]

    def building_row(self, side: int) -> None:
        """Buildings along one side, with gaps (side streets) showing buildings further back."""
        rng, p = self.rng, self.district_params()
        line = side * (self.edge[side > 0] + self.walk[side > 0])
        z, stop = rng.uniform(-25.0, -5.0), self.end if self.end is not None else 260.0
        while z < stop:
            if rng.random() < p["gap"]:
                width = rng.uniform(7.0, 18.0)
                if rng.random() < 0.5:
                    self.side_street(side, z, z + width)
                    back = rng.uniform(40.0, 80.0)
                else:
                    back = rng.uniform(10.0, 30.0)
                if rng.random() < 0.7:
                    self.back.append([])
                    self.building(side, z - 4.0, z + width + 4.0, line + side * back, self.back[-1])
                z += width
                continue
            width = min(rng.uniform(*p["width"]), stop - z + 1.0)
            setback = 0.0 if rng.random() < p["flush"] else rng.uniform(0.5, 5.0)
            group: list = []
            self.building(side, z, z + width, line + side * setback, group)
            self.buildings.append((z, group))
            z += width

    def side_street(self, side: int, z0: float, z1: float) -> None:
        """A road leaving at right angles through a gap: asphalt over the sidewalk, a curb across the view."""
        rng = self.rng
        inner = side * self.edge[side > 0]
        z0, z1 = z0 + rng.uniform(0.5, 2.0), z1 - rng.uniform(0.5, 2.0)
        road = flat(min(inner, inner + side * 90), max(inner, inner + side * 90), z0, z1)[0]
        self.surface(road, self.tar(), "asphalt", np.array([inner, 0.0, z0]))
        curb = rects(np.array([inner, 0.0, z1]), side * ACROSS, [0.0, 90.0, 0.0, self.curb])
        self.ground.append(("fill_many", (curb, self.lit(hsv(0.1, 0.05, rng.uniform(0.6, 0.85)), -ALONG))))

    def building(self, side: int, z0: float, z1: float, x: float, ops: list) -> None:
        """A block beside the street: its end wall facing the camera and its facade facing the street."""
        rng, p = self.rng, self.district_params()
        height = rng.uniform(*p["height"])
        style = str(rng.choice(p["styles"]))
        colour = self.facade_colour(style)
        wall_origin = np.array([x, 0.0, z0])
        depth = side * rng.uniform(8.0, 20.0)
        end_wall = rects(wall_origin, ACROSS * np.sign(depth), [0.0, abs(depth), 0.0, height])[0]
        ops.append(("fill", (end_wall, self.lit(colour, -ALONG), self.texture(style, wall_origin, ACROSS))))
        shop = rng.random() < p["shop"]
        ops += self.facade(wall_origin, ALONG, z1 - z0, height, ACROSS * -side, style, colour, shop)

    def end_row(self) -> None:
        """Buildings across the far end of the street, facing the camera: a grid of lines around the centre."""
        rng, x = self.rng, -200.0
        while x < 200.0:
            width = rng.uniform(10.0, 40.0)
            style = str(rng.choice(self.district_params()["styles"]))
            origin = np.array([x, 0.0, self.end])
            height = rng.uniform(*self.district_params()["height"]) * 1.2
            colour = self.facade_colour(style)
            self.back.append(self.facade(origin, ACROSS, width, height, -ALONG, style, colour, False))
            x += width

    def facade_colour(self, style: str) -> np.ndarray:
        """A plausible base colour for a wall of this style."""
        u = self.rng.uniform
        return {
            "plaster": lambda: hsv(u(0.0, 1.0) if u() < 0.3 else u(0.05, 0.17), u(0.05, 0.35), u(0.55, 0.95)),
            "bricks": lambda: hsv(u(0.0, 0.06), u(0.4, 0.7), u(0.35, 0.7)),
            "blocks": lambda: hsv(u(0.08, 0.14), u(0.05, 0.3), u(0.5, 0.85)),
            "panels": lambda: hsv(u(0.0, 1.0), u(0.0, 0.15), u(0.4, 0.85)),
            "planks": lambda: hsv(u(0.0, 1.0), u(0.1, 0.45), u(0.5, 0.9)),
        }[style]()

    def facade(
        self, origin: np.ndarray, along: np.ndarray, width: float, height: float, normal: np.ndarray,
        style: str, colour: np.ndarray, shop: bool,
    ) -> list:
        """A textured wall with cornice, floor bands, a grid of framed windows and maybe a shop front."""
        rng, ops = self.rng, []
        wall = rects(origin, along, [0.0, width, 0.0, height])[0]
        ops.append(("fill", (wall, self.lit(colour, normal), self.texture(style, origin, along))))
        trim = self.lit(colour * rng.uniform(0.6, 1.3), normal)
        floor_h, first = rng.uniform(2.8, 3.6), (rng.uniform(3.8, 4.6) if shop else rng.uniform(0.8, 1.3))
        if rng.random() < 0.4:  # floor bands: long horizontal lines across the whole wall
            levels = np.arange(first + floor_h - 0.3, height - 0.8, floor_h)
            bands = rects(origin, along, [[0.0, width, h, h + rng.uniform(0.12, 0.3)] for h in levels])
            ops.append(("fill_many", (bands, trim)))
        if rng.random() < 0.7:
            cornice = [0.0, width, height - rng.uniform(0.3, 0.8), height]
            ops.append(("fill_many", (rects(origin, along, cornice), trim)))
        ops += self.windows(origin, along, width, height, normal, floor_h, first)
        if shop:
            ops += self.shop_front(origin, along, width, normal)
        return ops

    def windows(
        self, origin: np.ndarray, along: np.ndarray, width: float, height: float, normal: np.ndarray,
        floor_h: float, first: float,
    ) -> list:
        """Framed windows on a grid of floors × bays, a few glass tints, maybe mullions and sills."""
        rng = self.rng
        bay = rng.uniform(1.6, 3.6)
        floors, bays = int((height - first - 0.8) // floor_h), int((width - 0.6) // bay)
        if floors < 1 or bays < 1 or (self.district == "industrial" and rng.random() < 0.4):
            return []
        ww, wh, fw = bay * rng.uniform(0.35, 0.75), floor_h * rng.uniform(0.35, 0.65), rng.uniform(0.04, 0.12)
        s0 = (width - bays * bay) / 2 + np.arange(bays) * bay + (bay - ww) / 2
        h0 = first + np.arange(floors) * floor_h
        s0, h0 = (a.ravel() for a in np.meshgrid(s0, h0))
        glass = np.stack([s0, s0 + ww, h0, h0 + wh], 1)
        frame_colour = hsv(0.0, 0.0, rng.uniform(0.1, 0.95))
        ops = [("fill_many", (rects(origin, along, glass + [-fw, fw, -fw, fw]), self.lit(frame_colour, normal)))]
        tints = [hsv(rng.uniform(0.5, 0.65), rng.uniform(0.1, 0.4), rng.uniform(0.1, 0.35)) for _ in range(2)]
        tints.append(hsv(rng.uniform(0.55, 0.6), rng.uniform(0.05, 0.2), rng.uniform(0.5, 0.8)))  # sky reflections
        pick = rng.choice(3, size=len(glass), p=[0.45, 0.35, 0.2])
        for i, tint in enumerate(tints):
            ops.append(("fill_many", (rects(origin, along, glass[pick == i]), tint * self.exposure)))
        if rng.random() < 0.5:  # mullions: a vertical and a horizontal bar in every window
            vertical = origin + (s0 + ww / 2)[:, None] * along + h0[:, None] * UP
            horizontal = origin + s0[:, None] * along + (h0 + wh * 0.66)[:, None] * UP
            segs = np.concatenate([
                np.stack([vertical, vertical + wh * UP], 1), np.stack([horizontal, horizontal + ww * along], 1)
            ])
            ops.append(("lines", (segs, self.lit(frame_colour, normal), 1)))
        if rng.random() < 0.5:
            sills = np.stack([s0 - fw - 0.05, s0 + ww + fw + 0.05, h0 - fw - 0.08, h0 - fw], 1)
            ops.append(("fill_many", (rects(origin, along, sills), self.lit(hsv(0.1, 0.05, 0.85), normal))))
        return ops

    def shop_front(self, origin: np.ndarray, along: np.ndarray, width: float, normal: np.ndarray) -> list:
        """Big ground-floor windows under a coloured sign band."""
        rng = self.rng
        n = max(1, int(width // rng.uniform(3.0, 6.0)))
        unit = width / n
        s0 = np.arange(n) * unit + unit * 0.08
        glass = np.stack([s0, s0 + unit * 0.84, np.full(n, 0.5), np.full(n, 2.6)], 1)
        sign = hsv(rng.uniform(), rng.uniform(0.5, 1.0), rng.uniform(0.5, 1.0))
        band = [unit * 0.1, width - unit * 0.1, 2.9, 2.9 + rng.uniform(0.5, 0.9)]
        return [
            ("fill_many", (rects(origin, along, glass), hsv(0.58, 0.2, rng.uniform(0.15, 0.4)) * self.exposure)),
            ("fill_many", (rects(origin, along, band), self.lit(sign, normal))),
        ]

    # --- road furniture --------------------------------------------------------------------------

    def furniture_row(self, side: int) -> None:
        """Lamp posts (maybe wired), signs, parked cars, trees and fences along one side."""
        rng, trees = self.rng, {"downtown": 0.15, "residential": 0.45, "industrial": 0.1}[self.district]
        if rng.random() < 0.75:
            self.lamps(side)
        for z in rng.uniform(4.0, 120.0, size=int(rng.integers(0, 4))):
            self.sign(side, z)
        if self.parking[side > 0]:
            self.parked_cars(side)
        if rng.random() < trees:
            self.trees(side)
        if rng.random() < 0.25:
            self.fence(side)
        if rng.random() < 0.2:
            self.signal(side, rng.uniform(12.0, min(self.stop(), 70.0)))

    def overhead(self) -> None:
        """Maybe a sign gantry spanning the street: two posts, a beam, big framed plates with 'text' bars."""
        rng = self.rng
        if rng.random() > 0.2:
            return
        z, height = rng.uniform(20.0, min(self.stop(), 120.0)), rng.uniform(5.5, 7.5)
        x0, x1 = -self.edge[0] - 0.6, self.edge[1] + 0.6
        metal = self.lit(hsv(0.0, 0.0, rng.uniform(0.35, 0.7)), -ALONG)
        origin = np.array([x0, 0.0, z])
        ops: list = [("fill_many", (np.concatenate([self.pole(x, z, height, 0.18) for x in (x0, x1)]), metal))]
        ops.append(("fill_many", (rects(origin, ACROSS, [0.0, x1 - x0, height - 0.7, height]), metal)))
        bays = np.linspace(0.0, x1 - x0, int((x1 - x0) // 1.5) + 1)
        low, high = origin + (height - 0.7) * UP, origin + height * UP
        zigzag = np.array([[low + a * ACROSS, high + b * ACROSS] for a, b in zip(bays[:-1], bays[1:], strict=True)])
        ops.append(("lines", (zigzag, metal * 0.6, 1)))
        board = hsv(rng.choice([0.33, 0.6]), rng.uniform(0.6, 0.9), rng.uniform(0.35, 0.6))
        white = self.lit(hsv(0.0, 0.0, 0.9), -ALONG)
        for a in np.sort(rng.uniform(0.5, x1 - x0 - 4.0, size=int(rng.integers(1, 3))))[:1 + (x1 - x0 > 12)]:
            w, h = rng.uniform(3.0, 5.0), rng.uniform(1.5, 2.5)
            top = height - 0.75
            inset = [a + 0.1, a + w - 0.1, top - h + 0.1, top - 0.1]
            ops.append(("fill_many", (rects(origin - [0, 0, 0.05], ACROSS, [a, a + w, top - h, top]), white)))
            ops.append(("fill_many", (rects(origin - [0, 0, 0.06], ACROSS, inset), self.lit(board, -ALONG))))
            rows = np.linspace(top - 0.45, top - h + 0.45, int(h // 0.45))
            text = [[a + 0.4, a + 0.4 + rng.uniform(0.3, 0.8) * (w - 0.8), r - 0.12, r] for r in rows]
            ops.append(("fill_many", (rects(origin - [0, 0, 0.07], ACROSS, text), white)))
        self.furniture.append((self.distance(0.0, z), ops))

    def signal(self, side: int, z: float) -> None:
        """A traffic-light mast arm reaching over the road, with signal heads hanging from it."""
        rng = self.rng
        x = side * (self.edge[side > 0] + 0.6)
        height, reach = rng.uniform(5.2, 6.5), rng.uniform(4.0, max(4.5, self.edge[side > 0] + 2.0))
        metal = self.lit(hsv(rng.uniform(0.2, 0.6), rng.uniform(0.0, 0.4), rng.uniform(0.2, 0.5)), -ALONG)
        origin = np.array([x, 0.0, z])
        ops: list = [("fill_many", (self.pole(x, z, height, 0.13), metal))]
        ops.append(("fill_many", (rects(origin, -side * ACROSS, [0.0, reach, height - 0.2, height]), metal)))
        for s in np.linspace(reach * 0.45, reach - 0.3, int(rng.integers(1, 4))):
            head = rects(origin - [0, 0, 0.05], -side * ACROSS, [s - 0.18, s + 0.18, height - 1.3, height - 0.2])
            ops.append(("fill_many", (head, hsv(0, 0, 0.07))))
            lit = int(rng.integers(3))
            lamps = [origin - [0, 0, 0.1] - side * s * ACROSS + (height - 0.45 - 0.33 * i) * UP for i in range(3)]
            for i, colour in enumerate((hsv(0.0, 0.9, 1.0), hsv(0.12, 0.9, 1.0), hsv(0.4, 0.9, 1.0))):
                ops.append(("discs", (lamps[i][None], np.array([0.11]), colour * (1.0 if i == lit else 0.25))))
        self.furniture.append((self.distance(x, z), ops))

    def stop(self) -> float:
        """How far down the street furniture goes (not through the end buildings)."""
        return min(self.end - 2.0, 150.0) if self.end is not None else 150.0

    def pole(self, x: float, z: float, height: float, radius: float) -> np.ndarray:
        """An upright pole at (x, z) as a quad turned to face the camera → (1, 4, 3)."""
        to_cam = np.array([self.camera.C[0] - x, 0.0, self.camera.C[2] - z])
        t = np.cross(to_cam / (np.linalg.norm(to_cam) + 1e-9), DOWN) * radius
        base = np.array([x, 0.0, z])
        return np.array([[base - t, base + t, base + t + height * UP, base - t + height * UP]])

    def lamps(self, side: int) -> None:
        """Evenly spaced lamp posts with arms over the road, and maybe wires from top to top."""
        rng = self.rng
        x = side * (self.edge[side > 0] + rng.uniform(0.4, 0.8))
        height, reach = rng.uniform(6.0, 10.0), rng.uniform(0.8, 2.5)
        zs = np.arange(rng.uniform(-10.0, 20.0), self.stop(), rng.uniform(15.0, 35.0))
        metal = self.lit(hsv(rng.uniform(0.2, 0.6), rng.uniform(0.0, 0.3), rng.uniform(0.2, 0.5)), -ALONG)
        for z in zs:
            arm = rects(np.array([x, 0.0, z]), -side * ACROSS, [0.0, reach, height - 0.12, height])
            head = rects(np.array([x, 0.0, z]), -side * ACROSS, [reach - 0.5, reach, height - 0.3, height - 0.1])
            ops = [
                ("fill_many", (self.pole(x, z, height, 0.09), metal)),
                ("fill_many", (arm, metal)),
                ("fill_many", (head, metal * 0.6)),
            ]
            self.furniture.append((self.distance(x, z), ops))
        if rng.random() < 0.4 and len(zs) > 1:
            tops = np.array([[x, -height + 0.05, z] for z in zs])
            wires = np.concatenate([np.stack([tops[:-1], tops[1:]], 1) + [0, dy, 0] for dy in (0.0, 0.5, 1.0)])
            self.furniture.append((self.distance(x, zs[0]) + 0.5, [("lines", (wires, metal * 0.5, 1))]))

    def sign(self, side: int, z: float) -> None:
        """A traffic sign facing the camera: rectangle, disc, triangle or diamond with a border."""
        rng = self.rng
        x = side * (self.edge[side > 0] + rng.uniform(0.3, 0.8))
        height, size = rng.uniform(2.2, 3.4), rng.uniform(0.5, 0.9)
        shape = int(rng.integers(4))
        angles = [
            np.linspace(0, 2 * np.pi, 24, endpoint=False),  # disc
            np.radians([90, 210, 330]),  # triangle
            np.radians([0, 90, 180, 270]),  # diamond
            np.radians([45, 135, 225, 315]),  # square
        ][shape]
        radius = size / 2 * (1.41 if shape == 3 else 1.0)
        centre = np.array([x, -height - size / 2, z])
        outline = centre + np.stack([np.cos(angles), -np.sin(angles), np.zeros_like(angles)], 1) * radius
        inner = centre + (outline - centre) * 0.8
        face = hsv(rng.choice([0.0, 0.6, 0.13, 0.33]), rng.uniform(0.6, 1.0), rng.uniform(0.5, 0.9))
        rim = hsv(0.0, 0.0, 0.9) if rng.random() < 0.6 else hsv(0.0, 0.9, 0.8)
        ops = [
            ("fill_many", (self.pole(x, z, height, 0.04), self.lit(hsv(0, 0, 0.5), -ALONG))),
            ("fill_many", (outline[None], self.lit(rim, -ALONG))),
            ("fill_many", (inner[None], self.lit(face, -ALONG))),
        ]
        self.furniture.append((self.distance(x, z), ops))

    def parked_cars(self, side: int) -> None:
        """A row of boxy cars along the curb, with gaps."""
        rng = self.rng
        x = side * (self.edge[side > 0] - rng.uniform(1.0, 1.2))
        z = rng.uniform(-4.0, 10.0)
        while z < min(self.stop(), 90.0):
            length = rng.uniform(3.8, 4.9)
            if rng.random() > 0.25:
                self.car(x, z, length)
            z += length + rng.uniform(0.6, 3.0)

    def car(self, x: float, z: float, length: float) -> None:
        """A two-box car centred at x, starting at z: body, glass cabin, roof, wheels."""
        rng = self.rng
        width = rng.uniform(1.65, 1.9)
        paint = hsv(rng.uniform(), rng.uniform(0.0, 0.8), rng.uniform(0.15, 0.9))
        body_top, roof = rng.uniform(0.9, 1.05), rng.uniform(1.35, 1.55)
        ops: list = []
        for dx in (-width / 2, width / 2 - 0.22):
            for dz in (0.5, length - 1.1):
                ops += self.box([x + dx, x + dx + 0.22, 0.0, 0.62, z + dz, z + dz + 0.62], hsv(0, 0, 0.08))
        ops += self.box([x - width / 2, x + width / 2, 0.3, body_top, z, z + length], paint)
        cabin = [x - width * 0.44, x + width * 0.44, body_top, roof, z + length * 0.25, z + length * 0.75]
        ops += self.box(cabin, hsv(0.6, 0.2, 0.18), top_colour=paint)
        self.furniture.append((self.distance(x, z), ops))

    def box(self, extent: list, colour: np.ndarray, top_colour: np.ndarray | None = None) -> list:
        """The camera-facing faces of an axis-aligned box (x0, x1, h0, h1, z0, z1), each shaded by its normal."""
        x0, x1, h0, h1, z0, z1 = extent
        c = self.camera.C
        faces = [
            (rects(np.array([x0, 0.0, z0]), ALONG, [0, z1 - z0, h0, h1])[0], -ACROSS, c[0] < x0),
            (rects(np.array([x1, 0.0, z0]), ALONG, [0, z1 - z0, h0, h1])[0], ACROSS, c[0] > x1),
            (rects(np.array([x0, 0.0, z0]), ACROSS, [0, x1 - x0, h0, h1])[0], -ALONG, c[2] < z0),
            (rects(np.array([x0, 0.0, z1]), ACROSS, [0, x1 - x0, h0, h1])[0], ALONG, c[2] > z1),
            (flat(x0, x1, z0, z1, h1)[0], UP, -c[1] > h1),
        ]
        ops = []
        for quad, normal, seen in faces:
            if seen:
                base = top_colour if top_colour is not None and normal is UP else colour
                ops.append(("fill_many", (quad[None], self.lit(base, normal))))
        return ops

    def trees(self, side: int) -> None:
        """Street trees: a trunk and a crown of overlapping leafy spheres."""
        rng = self.rng
        x = side * (self.edge[side > 0] + self.walk[side > 0] * rng.uniform(0.4, 0.8))
        for z in np.arange(rng.uniform(-5.0, 15.0), self.stop(), rng.uniform(10.0, 25.0)):
            trunk_h, crown = rng.uniform(1.8, 3.2), rng.uniform(1.0, 2.0)
            ops: list = [("fill_many", (self.pole(x, z, trunk_h + crown, 0.13), self.lit(hsv(0.08, 0.5, 0.3), -ALONG)))]
            centre = np.array([x, -(trunk_h + crown), z])
            leaf = hsv(rng.uniform(0.2, 0.35), rng.uniform(0.4, 0.8), rng.uniform(0.25, 0.5))
            for shade, count in ((0.6, 12), (0.85, 9), (1.1, 6)):  # dark inside, lit on top
                offsets = rng.normal(0.0, crown * 0.45, size=(count, 3)) + UP * crown * (shade - 0.6)
                radii = rng.uniform(0.4, 0.8, count) * crown
                ops.append(("discs", (centre + offsets, radii, self.lit(leaf * shade, UP))))
            self.furniture.append((self.distance(x, z), ops))

    def fence(self, side: int) -> None:
        """A railing along the outer edge of the sidewalk: posts and long rails."""
        rng = self.rng
        x = side * (self.edge[side > 0] + self.walk[side > 0] - 0.2)
        z0 = rng.uniform(-10.0, 30.0)
        z1 = min(z0 + rng.uniform(10.0, 60.0), self.stop())
        height = rng.uniform(0.9, 1.3)
        colour = self.lit(hsv(rng.uniform(), rng.uniform(0, 0.5), rng.uniform(0.1, 0.7)), -ALONG)
        posts = [self.pole(x, z, height, 0.04) for z in np.arange(z0, z1, rng.uniform(1.5, 2.5))]
        posts = np.concatenate(posts) if posts else np.zeros((0, 4, 3))
        levels = np.linspace(height * 0.4, height, int(rng.integers(2, 4)))
        rails = np.array([[[x, -h, z0], [x, -h, z1]] for h in levels])
        # Railings stand at the back of the sidewalk, behind other furniture: draw them first.
        self.furniture.append((np.inf, [("fill_many", (posts, colour)), ("lines", (rails, colour, 2))]))

    def distance(self, x: float, z: float) -> float:
        """Horizontal distance from the camera to (x, z): the painter's sort key for furniture."""
        return float(np.hypot(x - self.camera.C[0], z - self.camera.C[2]))


def random_street(rng: np.random.Generator, mount: Mount = CAR) -> Scene:
    """One random street scene seen from a camera posed as `mount` allows; all randomness comes from rng."""
    scene = Street(rng, mount).build()
    if mount.offset:
        # Moved once the street is built: its layout, textures and painter's order stay those of the unmoved
        # camera, so the frame is the same street from a viewpoint `offset` metres to the side (a stereo pair).
        camera = scene.camera
        scene.camera = Camera(R=camera.R, C=camera.C + mount.offset * camera.R[0])
    return scene
