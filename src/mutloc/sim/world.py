"""Scene description for the built-in renderer (:mod:`mutloc.sim.render`).

A :class:`World` is a room (floor, walls, ceiling with procedural textures),
a point light plus ambient light, a sensor model, and robots.  Each robot is
a rig :class:`~mutloc.core.rig.Robot` (camera + markers) with a world pose of
its camera (``Pose`` camera -> world, OpenCV optical frame), constant or a
function of time, and a simple grey body below and behind the camera.

World frame: z up, the floor is the plane z = 0, metres.

How each rig marker is drawn (first match wins):

- ``tag: {family, id, size, rotation?}``: the printed tag, OpenCV's own
  ``cv2.aruco.generateImageMarker`` image (families only the AprilTag
  library has: that library's layout) on a square card with a white
  margin of :data:`TAG_MARGIN_CELLS` cells.  ``size`` is the side of the
  square whose corners are the tag's corners (:func:`mutloc.detect.tags.tag_cells`).  Tag frame as in :mod:`mutloc.detect.tags` (the AprilTag
  library's): x right and y down as printed, z into the tag;
  ``X_robot = expm([rotation]x) @ X_tag + position``.  Default rotation
  :data:`DEFAULT_TAG_ROTATION` (pi about y): the tag faces forward (robot +z),
  upright for an upright camera in front of the robot.
- ``cylinder: {radius, height, code: [bits]}`` (in ``Marker.extra``): a
  vertical cylinder (axis along the robot's y; a robot with ``cameras``:
  along its z, :func:`cylinder_up`) centred on ``position``, wrapped in
  ``len(code)`` equal rings; ``code[0]`` is the *top* ring (robot -y side;
  +z), bit 1 = dark, 0 = light.  Caps are mid grey.
- ``blink_hz``: an emissive sphere (radius ``extra['radius']``, default
  :data:`DEFAULT_LIGHT_RADIUS`) of ``color`` (default white), on during the
  first half of each period: on iff ``frac(blink_hz * t + phase) < 0.5`` with
  ``phase = extra.get('phase', 0)`` in cycles (see :func:`light_is_on`).
- otherwise a matte ball of ``color`` (default light grey), radius
  ``extra['radius']`` or :data:`DEFAULT_BALL_RADIUS`.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from ..core.camera import Camera
from ..core.pose import Pose
from ..core.rig import CAMERA_SEPARATOR, Marker, MarkerKind, Mount, Rig, Robot
from ..errors import InputError, ObservationError, RigError
from ..detect.tags import aruco_dictionary, square_corners, tag_cells, tag_library, tag_rotation
from ..detect.tags import tag_spec as detect_tag_spec

__all__ = [
    "DEFAULT_BALL_RADIUS",
    "DEFAULT_LIGHT_RADIUS",
    "DEFAULT_TAG_ROTATION",
    "LIGHT_EMISSION",
    "MARKER_KINDS",
    "TAG_MARGIN_CELLS",
    "Light",
    "PROP_KINDS",
    "Plastic",
    "PoseLike",
    "Prop",
    "Room",
    "Sensor",
    "World",
    "WorldRobot",
    "aruco_dictionary",
    "ball_radius",
    "camera_to_world_facing",
    "cylinder_spec",
    "cylinder_up",
    "light_is_on",
    "room_textures",
    "standard_rig",
    "tag_corners",
    "tag_image",
    "tag_scale",
    "tag_spec",
]

DEFAULT_BALL_RADIUS = 0.03
DEFAULT_LIGHT_RADIUS = 0.02
# Linear radiance of a lit LED's brightest channel: > 1 so its core saturates
# and the bloom halo is visible, like a real LED at normal exposure.
LIGHT_EMISSION = 4.0
# White quiet zone around the black square of a printed tag, in tag cells.
TAG_MARGIN_CELLS = 1
DEFAULT_TAG_ROTATION = (0.0, math.pi, 0.0)
# Albedo (sRGB 0-255) of tag cells: real paper and ink are neither 0 nor 1.
_TAG_BLACK, _TAG_WHITE = 20, 235

PoseLike = Pose | Callable[[float], Pose]


# ---------------------------------------------------------------------------
# markers
# ---------------------------------------------------------------------------


def _positive(value: Any, what: str, marker: Marker) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not (math.isfinite(float(value)) and float(value) > 0):
        raise RigError(f"marker {marker.name!r}: {what} must be a finite number > 0, got {value!r}")
    return float(value)


def ball_radius(marker: Marker) -> float:
    """Sphere radius (m) of a ball or light marker (``extra['radius']`` or the default)."""
    default = DEFAULT_LIGHT_RADIUS if marker.kind == MarkerKind.LIGHT else DEFAULT_BALL_RADIUS
    r = marker.extra.get("radius")
    return default if r is None else _positive(r, "radius", marker)


def _phase(marker: Marker) -> float:
    ph = marker.extra.get("phase", 0.0)
    if isinstance(ph, bool) or not isinstance(ph, (int, float, np.integer, np.floating)) or not math.isfinite(ph):
        raise RigError(f"marker {marker.name!r}: phase must be a finite number (cycles), got {ph!r}")
    return float(ph)


def light_is_on(marker: Marker, t: float) -> bool:
    """State of a blinking light at time ``t`` (s): a 50 % duty square wave.

    On iff ``frac(blink_hz * t + phase) < 0.5``, ``phase`` in cycles.  A tiny
    tolerance makes frame times such as ``k / fps`` that land exactly on a
    switching instant come out the same despite round-off.
    """
    if marker.blink_hz is None:
        return True
    x = marker.blink_hz * float(t) + _phase(marker)
    return ((x + 1e-9) % 1.0) < 0.5


def tag_spec(marker: Marker) -> tuple[str, int, float, np.ndarray]:
    """``(family, id, size, R_robot_tag)`` of a tag marker, validated (RigError);
    a tag without ``rotation`` faces forward, upright."""
    family, tid, size = detect_tag_spec(marker)
    return family, tid, size, tag_rotation(marker, DEFAULT_TAG_ROTATION)


def tag_scale(family: str, tag_id: int) -> float:
    """Side of the whole card (:func:`tag_image`) over the rig's tag ``size``."""
    return tag_image(family, tag_id).shape[0] / tag_cells(family)


@functools.lru_cache(maxsize=256)
def tag_image(family: str, tag_id: int) -> np.ndarray:
    """The tag as printed, one pixel per cell, uint8 (n, n), white margin included."""
    if tag_library(family) == "apriltag" and family not in ("tag16h5", "tag25h9", "tag36h11"):
        from ..detect.apriltag_lib import tag_image as library_tag_image

        img = library_tag_image(family, int(tag_id))
    else:
        d = aruco_dictionary(family)
        cells = int(d.markerSize) + 2
        img = cv2.aruco.generateImageMarker(d, int(tag_id), cells, borderBits=1)
    img = np.where(img > 127, _TAG_WHITE, _TAG_BLACK).astype(np.uint8)
    m = TAG_MARGIN_CELLS
    out = np.pad(img, m, constant_values=_TAG_WHITE)
    out.flags.writeable = False
    return out


def tag_corners(marker: Marker) -> np.ndarray:
    """Corners (4, 3) of the black square in the robot frame, OpenCV order
    (top-left, top-right, bottom-right, bottom-left as printed)."""
    _, _, size, R = tag_spec(marker)
    return square_corners(marker.position, size, R)


def cylinder_spec(marker: Marker) -> tuple[float, float, np.ndarray]:
    """``(radius, height, code)`` of a banded-cylinder marker, validated (RigError)."""
    spec = marker.extra.get("cylinder")
    w = f"marker {marker.name!r}: cylinder"
    if not isinstance(spec, Mapping):
        raise RigError(f"{w} must be a mapping {{radius, height, code}}, got {spec!r}")
    for key in ("radius", "height", "code"):
        if key not in spec:
            raise RigError(f"{w}: missing key {key!r}")
    radius = _positive(spec["radius"], "cylinder radius", marker)
    height = _positive(spec["height"], "cylinder height", marker)
    code = spec["code"]
    if not isinstance(code, (list, tuple)) or not code or not all(
            not isinstance(b, bool) and b in (0, 1) for b in code) or len(code) > 64:
        raise RigError(f"{w}: code must be a list of 1 to 64 bits (0 or 1), got {code!r}")
    return radius, height, np.asarray(code, dtype=np.int64)


def cylinder_up(body: bool) -> np.ndarray:
    """The direction, in its robot's frame, of a banded cylinder's axis towards its top band (``code[0]``):
    the robot's -y for a robot given with one ``camera`` (its frame is that camera's optical frame, y
    down), +z for a robot with ``cameras`` (a body frame, z up: ``base_link``, REP 103).  Either way the
    cylinder stands upright on a robot driving on a floor."""
    return np.array([0.0, 0.0, 1.0]) if body else np.array([0.0, -1.0, 0.0])


# ---------------------------------------------------------------------------
# light, sensor, room
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Light:
    """A point light plus uniform ambient light.

    Radiance of a matte surface = albedo * colour * (ambient + visible *
    intensity * max(0, n.l)), where ``visible`` is 0 in the shadow of
    another object when ``shadows`` is on (a hard light: a point source, so
    shadows have sharp edges).  ``position`` is in the world frame; None
    puts it near the ceiling above the robots.  ``color`` is the light's
    sRGB colour (warm tungsten is about (255, 180, 110)); white by default.
    """

    position: tuple[float, float, float] | None = None
    intensity: float = 0.75
    ambient: float = 0.35
    color: tuple[int, int, int] = (255, 255, 255)
    shadows: bool = False

    def __post_init__(self) -> None:
        for what in ("intensity", "ambient"):
            v = getattr(self, what)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputError(f"light {what} must be a finite number >= 0, got {v!r}")
        if len(self.color) != 3 or not all(0 <= float(c) <= 255 for c in self.color):
            raise InputError(f"light color must be (r, g, b) in 0..255, got {self.color!r}")


@dataclass(frozen=True)
class Plastic:
    """Glossy finish of the balls: a Blinn-Phong highlight of the light's colour.

    Radiance added on a ball = ``specular * intensity * colour * (n.h) ** shininess``
    where the light reaches it; the highlight is not tinted by the ball's
    albedo, as on real plastic (a dielectric reflects white).
    """

    specular: float = 0.5
    shininess: float = 60.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.specular) and self.specular >= 0):
            raise InputError(f"specular must be a finite number >= 0, got {self.specular!r}")
        if not (math.isfinite(self.shininess) and self.shininess >= 1):
            raise InputError(f"shininess must be a finite number >= 1, got {self.shininess!r}")


PROP_KINDS = ("pole", "box")


@dataclass(frozen=True)
class Prop:
    """A static object of the room, in the world frame: an occluder or clutter.

    ``kind`` ``"pole"``: a capped cylinder (poles, cables) centred on
    ``centre`` along the direction ``axis``, ``size = (radius, length)``.
    ``kind`` ``"box"``: a box (box edges, same-hue clutter) of half extents
    ``size = (hx, hy, hz)`` turned by the rotation vector ``axis`` (radians).
    ``color`` is sRGB (r, g, b), matte.
    """

    kind: str
    centre: tuple[float, float, float]
    size: tuple[float, ...]
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    color: tuple[int, int, int] = (90, 90, 90)

    def __post_init__(self) -> None:
        if self.kind not in PROP_KINDS:
            raise InputError(f"prop kind must be one of {', '.join(PROP_KINDS)}, got {self.kind!r}")
        n = 2 if self.kind == "pole" else 3
        try:
            vals = [float(x) for x in self.size] + [float(x) for x in self.centre] + [float(x) for x in self.axis]
        except (TypeError, ValueError):
            raise InputError(f"prop {self.kind}: centre, size and axis must be numbers") from None
        if len(self.size) != n or len(self.centre) != 3 or len(self.axis) != 3 or not all(map(math.isfinite, vals)):
            raise InputError(f"prop {self.kind}: needs centre (3), size ({n}) and axis (3), finite")
        if any(float(x) <= 0 for x in self.size):
            raise InputError(f"prop {self.kind}: size must be positive, got {self.size!r}")
        if self.kind == "pole" and math.hypot(*map(float, self.axis)) < 1e-12:
            raise InputError("prop pole: axis must be a non-zero direction")
        if len(self.color) != 3 or not all(0 <= float(c) <= 255 for c in self.color):
            raise InputError(f"prop color must be (r, g, b) in 0..255, got {self.color!r}")


@dataclass(frozen=True)
class Sensor:
    """Camera response: ``DN = 255 * srgb(clip(gain * exposure * radiance)) + N(0, gain * noise_sigma)``.

    ``blur_angle_deg`` is the direction of :func:`~mutloc.sim.render.render`'s
    linear motion blur in the image (0 = along +u); ``bloom_sigma_px`` and
    ``bloom_strength`` shape the glow around lit lights.
    """

    exposure: float = 1.0
    gain: float = 1.0
    blur_angle_deg: float = 0.0
    #: Optical blur (defocus, lens): a Gaussian point-spread function of this
    #: standard deviation in pixels, applied in linear light before encoding.
    psf_sigma_px: float = 0.0
    bloom_sigma_px: float = 4.0
    bloom_strength: float = 0.6


@dataclass(frozen=True)
class Room:
    """An axis-aligned box room: floor at z = 0, walls, ceiling at ``height``.

    ``center``/``size`` are the floor's centre and extent (x, y) in metres;
    ``seed`` drives the procedural textures; ``texel`` is their resolution (m).
    """

    center: tuple[float, float] = (0.0, 0.0)
    size: tuple[float, float] = (8.0, 8.0)
    height: float = 2.6
    seed: int = 0
    texel: float = 0.005
    # Printed mats on the floor (per square metre): distinctive texture that
    # cameras facing each other both see, for feature-matching baselines.
    floor_decals: float = 0.0
    # A word of text on each wall poster.  The words are drawn by OpenCV's
    # text renderer (cv2.putText), whose glyphs are not the same from one
    # OpenCV release to the next (5.1 rasterises FONT_HERSHEY_SIMPLEX unlike
    # 5.0, up to 230 grey levels apart on a poster's letters); every other
    # texture call is bit-identical across releases.  Without the words the
    # textures, hence the rendered frames, do not depend on the OpenCV
    # version: for tests that need a scene's exact pixels.
    poster_text: bool = True

    def surfaces(self) -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray, float, float]]:
        """``(name, centre, u, v, half_u, half_v)`` of each inner surface.

        ``u`` is "right" and ``v`` "up" for a viewer inside the room facing the
        surface, so textures (text on posters) read the right way round; the
        inward normal is ``u x v``.
        """
        cx, cy = map(float, self.center)
        sx, sy = (0.5 * float(s) for s in self.size)
        H = float(self.height)
        X, Y, Z = np.eye(3)
        return [
            ("floor", np.array([cx, cy, 0.0]), X, Y, sx, sy),
            ("ceiling", np.array([cx, cy, H]), X, -Y, sx, sy),
            ("wall_xp", np.array([cx + sx, cy, H / 2]), -Y, Z, sy, H / 2),
            ("wall_xn", np.array([cx - sx, cy, H / 2]), Y, Z, sy, H / 2),
            ("wall_yp", np.array([cx, cy + sy, H / 2]), X, Z, sx, H / 2),
            ("wall_yn", np.array([cx, cy - sy, H / 2]), -X, Z, sx, H / 2),
        ]


def _noise(rng: np.random.Generator, h: int, w: int, cells: float, texel: float) -> np.ndarray:
    """Smooth value noise (float32, ~unit std) with features ``cells`` metres across."""
    gh = max(2, int(round(h * texel / cells)) + 1)
    gw = max(2, int(round(w * texel / cells)) + 1)
    g = rng.standard_normal((gh, gw)).astype(np.float32)
    return cv2.resize(g, (w, h), interpolation=cv2.INTER_CUBIC)


def _random_text(rng: np.random.Generator, n: int) -> str:
    letters = "ABCDEFGHJKLMNPRSTUVWXYZ0123456789"
    return "".join(letters[i] for i in rng.integers(0, len(letters), n))


def _texture(name: str, w: int, h: int, texel: float, rng: np.random.Generator, decals: float = 0.0,
             text: bool = True) -> np.ndarray:
    """sRGB uint8 (h, w, 3) BGR texture of one room surface (row 0 = top / far +v side)."""
    px = lambda metres: max(1, int(round(metres / texel)))
    if name == "floor":
        # Tiles in two tones with dark grout, mottled, with speckles: plenty of
        # corners and blobs for feature matching, no exact repetition.
        base = np.array([118, 128, 140], np.float32)
        img = np.empty((h, w, 3), np.float32)
        img[:] = base
        tile = px(0.5)
        yy, xx = np.mgrid[0:h, 0:w]
        checker = ((yy // tile + xx // tile) % 2).astype(np.float32)
        img += (checker * 28.0 - 14.0)[..., None]
        img += (12.0 * _noise(rng, h, w, 0.6, texel) + 7.0 * _noise(rng, h, w, 0.08, texel))[..., None]
        img = np.clip(img, 0, 255).astype(np.uint8)
        grout = max(1, px(0.008))
        for x in range(0, w, tile):
            img[:, x:x + grout] = (60, 62, 66)
        for y in range(0, h, tile):
            img[y:y + grout, :] = (60, 62, 66)
        n = int(w * h * texel * texel * 25)
        for _ in range(n):
            c = (int(rng.integers(0, w)), int(rng.integers(0, h)))
            shade = int(rng.choice([rng.integers(25, 70), rng.integers(180, 240)]))
            cv2.circle(img, c, px(rng.uniform(0.006, 0.025)), (shade, shade, shade), -1, cv2.LINE_AA)
        for _ in range(int(round(w * h * texel * texel * decals))):
            pw, ph = px(rng.uniform(0.2, 0.6)), px(rng.uniform(0.2, 0.6))
            x0, y0 = int(rng.integers(0, max(1, w - pw))), int(rng.integers(0, max(1, h - ph)))
            _poster(img, rng, x0, y0, pw, ph, 8, 20, text)
        return img
    if name == "ceiling":
        img = np.full((h, w, 3), 205, np.float32)
        img += (6.0 * _noise(rng, h, w, 0.3, texel))[..., None]
        img = np.clip(img, 0, 255).astype(np.uint8)
        panel = px(0.6)
        for x in range(0, w, panel):
            img[:, x:x + 2] = 150
        for y in range(0, h, panel):
            img[y:y + 2, :] = 150
        return img
    # Walls: a pastel base, mottled, with posters of shapes and random text.
    hue = rng.uniform(0, 180)
    base = cv2.cvtColor(np.array([[[hue, rng.uniform(25, 60), rng.uniform(170, 215)]]], np.uint8),
                        cv2.COLOR_HSV2BGR)[0, 0].astype(np.float32)
    img = np.empty((h, w, 3), np.float32)
    img[:] = base
    img += (10.0 * _noise(rng, h, w, 0.5, texel) + 4.0 * _noise(rng, h, w, 0.05, texel))[..., None]
    img = np.clip(img, 0, 255).astype(np.uint8)
    # A skirting board along the floor.
    img[h - px(0.1):, :] = (70, 80, 90)
    n_posters = max(3, int(w * texel * 2.2))
    for _ in range(n_posters):
        pw, ph = px(rng.uniform(0.25, 0.9)), px(rng.uniform(0.25, 0.9))
        x0 = int(rng.integers(0, max(1, w - pw)))
        y0 = int(rng.integers(px(0.35), max(px(0.36), h - ph - px(0.4))))
        _poster(img, rng, x0, y0, pw, ph, 3, 9, text)
    return img


def _poster(img: np.ndarray, rng: np.random.Generator, x0: int, y0: int, pw: int, ph: int,
            lo: int, hi: int, text: bool = True) -> None:
    """Draw a coloured card with ``lo..hi`` random shapes and (``text``) a word of text."""
    col = tuple(int(c) for c in rng.integers(30, 240, 3))
    cv2.rectangle(img, (x0, y0), (x0 + pw, y0 + ph), col, -1)
    for _ in range(int(rng.integers(lo, hi))):
        kind = int(rng.integers(0, 3))
        c2 = tuple(int(c) for c in rng.integers(0, 256, 3))
        cx, cy = x0 + int(rng.integers(0, pw)), y0 + int(rng.integers(0, ph))
        if kind == 0:
            cv2.circle(img, (cx, cy), int(rng.integers(3, max(4, min(pw, ph) // 4))), c2, -1, cv2.LINE_AA)
        elif kind == 1:
            cv2.rectangle(img, (cx, cy), (cx + int(rng.integers(4, max(5, pw // 3))),
                                          cy + int(rng.integers(4, max(5, ph // 3)))), c2, -1)
        else:
            cv2.line(img, (cx, cy), (x0 + int(rng.integers(0, pw)), y0 + int(rng.integers(0, ph))), c2,
                     int(rng.integers(1, 5)), cv2.LINE_AA)
    word = _random_text(rng, int(rng.integers(3, 7)))  # drawn or not, the same draws
    if not text:
        return
    scale = max(0.3, ph / 160.0)
    cv2.putText(img, word, (x0 + 4, y0 + ph - 6),
                cv2.FONT_HERSHEY_SIMPLEX, scale, (20, 20, 20), max(1, int(scale * 2)), cv2.LINE_AA)


def room_textures(room: Room) -> dict[str, np.ndarray]:
    """sRGB BGR uint8 texture of each surface of ``room`` (deterministic in ``room.seed``).

    Texel (i, j) covers ``u`` in ``[-half_u + j*texel, ...)`` and ``v`` from the
    top (``+half_v``) down.  Cached on (size, height, seed, texel): rooms that
    differ only in where they stand share their textures.
    """
    return _room_textures(tuple(map(float, room.size)), float(room.height), int(room.seed), float(room.texel),
                          float(room.floor_decals), bool(room.poster_text))


@functools.lru_cache(maxsize=4)
def _room_textures(size: tuple[float, float], height: float, seed: int, texel: float,
                   decals: float = 0.0, text: bool = True) -> dict[str, np.ndarray]:
    room = Room(size=size, height=height, seed=seed, texel=texel, floor_decals=decals, poster_text=text)
    out = {}
    for k, (name, _c, _u, _v, hu, hv) in enumerate(room.surfaces()):
        rng = np.random.default_rng([seed & 0xFFFFFFFF, 7919, k])
        w = max(2, int(math.ceil(2 * hu / texel)))
        h = max(2, int(math.ceil(2 * hv / texel)))
        tex = _texture(name, w, h, texel, rng, decals if name == "floor" else 0.0, text)
        tex.flags.writeable = False
        out[name] = tex
    return out


# ---------------------------------------------------------------------------
# robots and the world
# ---------------------------------------------------------------------------


def camera_to_world_facing(position: Any, yaw: float = 0.0, pitch: float = 0.0) -> Pose:
    """Camera -> world pose of an upright camera at ``position`` (world, z up).

    ``yaw`` (radians, about world z) 0 looks along world +x; ``pitch`` > 0
    looks up.
    """
    # Columns: the camera's x (right), y (down), z (forward) in the world.
    cy, sy = math.cos(yaw), math.sin(yaw)
    cp, sp = math.cos(pitch), math.sin(pitch)
    fwd = np.array([cy * cp, sy * cp, sp])
    right = np.array([sy, -cy, 0.0])
    down = np.cross(fwd, right)
    return Pose(np.column_stack([right, down, fwd]), np.asarray(position, dtype=float))


@dataclass
class WorldRobot:
    """A robot in the world: rig robot + robot->world pose (constant or ``pose(t)``).

    For a robot given with one ``camera`` the robot's frame is that camera's
    optical frame, so ``pose`` is the camera's pose; for a robot with
    ``cameras`` it is the body frame's pose (z up: ``base_link``), and each
    camera is at ``pose @ mount.pose``.  ``body`` draws a grey box: below and
    behind a one-camera robot's camera, or (robot with ``cameras``) a box
    standing on the robot's origin, clear of its cameras and markers (see
    :func:`mutloc.sim.render.body_box`).
    """

    robot: Robot
    pose: PoseLike
    body: bool = True
    body_color: tuple[int, int, int] = (128, 128, 128)

    @property
    def name(self) -> str:
        return self.robot.name

    def pose_at(self, t: float = 0.0) -> Pose:
        """Robot -> world pose at time ``t`` (the camera's for a robot with one camera)."""
        p = self.pose(float(t)) if callable(self.pose) else self.pose
        if not isinstance(p, Pose):
            raise InputError(f"robot {self.name!r}: pose must be a Pose (or return one), got {type(p).__name__}")
        return p


@dataclass
class World:
    """Robots in a room, lit, seen through a sensor model.  See the module docstring."""

    robots: dict[str, WorldRobot]
    room: Room | None = None
    light: Light = field(default_factory=Light)
    sensor: Sensor = field(default_factory=Sensor)
    background: tuple[int, int, int] = (0, 0, 0)  # sRGB of rays that hit nothing
    #: Static objects of the room (occluders, clutter); none by default.
    props: tuple[Prop, ...] = ()
    #: Glossy balls (:class:`Plastic`); None: matte.
    ball_finish: Plastic | None = None

    def robot(self, name: str) -> WorldRobot:
        try:
            return self.robots[name]
        except KeyError:
            raise ObservationError(f"unknown robot {name!r} (world has {sorted(self.robots)})") from None

    def observer(self, key: str) -> tuple[str, str]:
        """``(robot, camera)`` of an observer key: ``ROBOT`` (a robot with one camera; camera ``""`` for one
        given with ``camera:``) or ``ROBOT/CAMERA``, as :meth:`mutloc.core.rig.Rig.observer`."""
        wr = self.robots.get(key)
        if wr is not None:
            cams = wr.robot.cameras
            if cams is None:
                return key, ""
            if len(cams) == 1:
                return key, next(iter(cams))
            raise ObservationError(f"robot {key!r} has cameras {', '.join(cams)}: name one "
                                   f"({key}{CAMERA_SEPARATOR}{next(iter(cams))}, ...)")
        rname, sep, cname = str(key).rpartition(CAMERA_SEPARATOR)
        wr = self.robots.get(rname) if sep else None
        if wr is None:
            raise ObservationError(f"unknown robot {key!r} (world has {sorted(self.robots)})")
        if wr.robot.cameras is None or cname not in wr.robot.cameras:
            has = (f"cameras {', '.join(wr.robot.cameras)}" if wr.robot.cameras is not None
                   else f"one camera: name it {rname!r}")
            raise ObservationError(f"unknown camera {key!r} (robot {rname!r} has {has})")
        return rname, cname

    def mount(self, key: str) -> Mount:
        """The camera (lens and pose in its robot's frame) an observer key names."""
        rname, cname = self.observer(key)
        return self.robots[rname].robot.mounts[cname]

    def camera(self, name: str) -> Any:
        """The lens of observer ``name`` (``ROBOT`` or ``ROBOT/CAMERA``): a Camera, FisheyeCamera or OmniCamera."""
        return self.mount(name).camera

    def pose(self, name: str, t: float = 0.0) -> Pose:
        """Robot -> world pose of robot ``name`` at time ``t`` (for a robot given with one ``camera``: its
        camera's; for a robot with ``cameras``: its body frame's, see :meth:`camera_pose`)."""
        return self.robot(name).pose_at(t)

    def camera_pose(self, key: str, t: float = 0.0) -> Pose:
        """Camera -> world pose of observer ``key`` at ``t``: ``T_world_robot @ T_robot_camera``
        (the robot's pose itself for a robot given with one ``camera``)."""
        rname, cname = self.observer(key)
        T = self.robot(rname).pose_at(t)
        if cname == "":
            return T
        return T @ self.robots[rname].robot.cameras[cname].pose

    def light_position(self) -> np.ndarray:
        """World position of the point light (default: near the ceiling above the robots at t = 0)."""
        if self.light.position is not None:
            return np.asarray(self.light.position, dtype=float)
        # From the poses at t = 0 only, so the light does not move with the robots.
        c = np.mean([self.pose(n, 0.0).t for n in self.robots], axis=0)
        top = self.room.height - 0.2 if self.room is not None else 2.4
        # Off to one side so spheres show a clear terminator, as under real lamps.
        return np.array([c[0] + 0.7, c[1] - 0.9, top])


# ---------------------------------------------------------------------------
# the standard simulation rig
# ---------------------------------------------------------------------------

MARKER_KINDS = ("balls", "lights", "tags", "cylinders")

# Marker layout of the standard rig (as mutloc.sim.synthetic.USUAL_MARKERS):
# left and right of the camera, a little above and behind it.
_STANDARD_LAYOUT = {"q": {"M1": (-0.15, -0.05, -0.03), "M2": (0.15, -0.05, -0.03)},
                    "p": {"M3": (-0.15, -0.05, -0.03), "M4": (0.15, -0.05, -0.03)}}
_STANDARD_COLORS = {"M1": (0, 0, 255), "M2": (255, 255, 0), "M3": (255, 0, 0), "M4": (0, 255, 0)}
_STANDARD_BLINK = {"M1": 2.0, "M2": 3.0, "M3": 5.0, "M4": 7.5}
_STANDARD_TAG_IDS = {"M1": 0, "M2": 1, "M3": 2, "M4": 3}
# Framed by dark bands at both ends so the code's extent is visible on any background.
_STANDARD_CODES = {"M1": [1, 0, 1, 0, 0, 1], "M2": [1, 1, 0, 1, 0, 1], "M3": [1, 0, 0, 1, 1, 1],
                   "M4": [1, 1, 1, 0, 0, 1]}


def standard_rig(markers: str = "balls", *, size: tuple[int, int] = (960, 540), f: float = 800.0,
                 k1: float = 0.0) -> Rig:
    """The rig ``mutloc simulate`` uses: robots ``p`` (M3, M4) and ``q`` (M1, M2).

    Identical cameras (focal ``f`` px, centred principal point, radial ``k1``)
    and two markers per robot of kind ``markers`` (:data:`MARKER_KINDS`).
    """
    if markers not in MARKER_KINDS:
        raise InputError(f"unknown marker kind {markers!r} (one of {', '.join(MARKER_KINDS)})")
    w, h = int(size[0]), int(size[1])
    K = np.array([[f, 0.0, (w - 1) / 2.0], [0.0, f, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
    cam = Camera(K, [k1, 0.0, 0.0, 0.0, 0.0], (w, h))
    robots = {}
    for rname in ("p", "q"):
        ms = {}
        for mname, pos in _STANDARD_LAYOUT[rname].items():
            kw: dict[str, Any] = {}
            extra: dict[str, Any] = {}
            if markers == "balls":
                kw["color"] = _STANDARD_COLORS[mname]
                extra["radius"] = DEFAULT_BALL_RADIUS
            elif markers == "lights":
                kw["color"] = _STANDARD_COLORS[mname]
                kw["blink_hz"] = _STANDARD_BLINK[mname]
                extra["radius"] = DEFAULT_LIGHT_RADIUS
            elif markers == "tags":
                kw["tag"] = {"family": "tag36h11", "id": _STANDARD_TAG_IDS[mname], "size": 0.1,
                             "rotation": list(DEFAULT_TAG_ROTATION)}
            else:
                extra["cylinder"] = {"radius": 0.03, "height": 0.12, "code": list(_STANDARD_CODES[mname])}
            ms[mname] = Marker(mname, rname, np.array(pos, dtype=float), extra=extra, **kw)
        robots[rname] = Robot(rname, cam, ms)
    return Rig(robots)
