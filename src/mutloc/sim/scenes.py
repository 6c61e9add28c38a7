"""Harder scenes for the renderer: real light and partly hidden markers.

Each function takes a :class:`~mutloc.sim.world.World` and returns a new
one (or the props to add), so any standard world can be made harder:

- :func:`lit`: one of :data:`LIGHTINGS`: ``"hard"`` (one point light with
  hard shadows, little ambient, glossy plastic balls with specular
  highlights), ``"dim"``, ``"warm"`` (tungsten-coloured light) and
  ``"backlit"`` (the light behind the robot the observer looks at, so the
  balls face the camera in their own shade against a brighter background).
- :func:`occluder`: a pole, a cable or the edge of a box placed just in
  front of a ball so that it hides a chosen share of the ball's image.
- :func:`same_hue_clutter`: boxes of a ball's own colour near it.

The renderer's defaults are untouched: a world only changes when one of
these is applied.
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

from ..errors import InputError, ObservationError
from .world import Light, Plastic, Prop, World, ball_radius

__all__ = ["LIGHTINGS", "OCCLUDERS", "hidden_share", "lit", "occluder", "same_hue_clutter", "with_props"]

LIGHTINGS = ("even", "hard", "dim", "warm", "backlit")
OCCLUDERS = ("pole", "cable", "box")

# Warm white (about 2700 K) as sRGB.
_TUNGSTEN = (255, 176, 96)
_PLASTIC = Plastic(specular=0.6, shininess=60.0)


def lit(world: World, lighting: str, *, observer: str | None = None, target: str | None = None,
        seed: int = 0) -> World:
    """``world`` under one of :data:`LIGHTINGS` (``"even"``: unchanged).

    ``observer`` and ``target`` (robot names) place the ``"backlit"`` light
    behind ``target`` as ``observer`` sees it; by default the first and
    second robots.  ``seed`` moves the hard light around a little.
    """
    if lighting not in LIGHTINGS:
        raise InputError(f"unknown lighting {lighting!r} (one of {', '.join(LIGHTINGS)})")
    if lighting == "even":
        return world
    names = list(world.robots)
    obs = observer if observer is not None else names[0]
    tgt = target if target is not None else next(n for n in names if n != obs)
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 7717])
    base = world.light_position() + rng.uniform(-0.3, 0.3, 3) * np.array([1.0, 1.0, 0.3])
    if lighting == "hard":
        light = Light(tuple(base), intensity=1.1, ambient=0.06, shadows=True)
    elif lighting == "dim":
        light = Light(tuple(base), intensity=0.16, ambient=0.04, shadows=True)
    elif lighting == "warm":
        light = Light(tuple(base), intensity=0.8, ambient=0.2, color=_TUNGSTEN, shadows=True)
    else:
        c_obs = world.pose(obs).t
        c_tgt = world.pose(tgt).t
        d = c_tgt - c_obs
        d[2] = 0.0
        d /= max(np.linalg.norm(d), 1e-9)
        pos = c_tgt + 1.2 * d + np.array([0.0, 0.0, 1.0]) + rng.uniform(-0.2, 0.2, 3)
        if world.room is not None:
            # Keep the lamp inside the room.
            (cx, cy), (sx, sy) = world.room.center, world.room.size
            pos[0] = np.clip(pos[0], cx - sx / 2 + 0.1, cx + sx / 2 - 0.1)
            pos[1] = np.clip(pos[1], cy - sy / 2 + 0.1, cy + sy / 2 - 0.1)
            pos[2] = min(pos[2], world.room.height - 0.1)
        light = Light(tuple(pos), intensity=1.6, ambient=0.08, shadows=True)
    return dataclasses.replace(world, light=light, ball_finish=_PLASTIC)


def with_props(world: World, *props: Prop) -> World:
    """``world`` with ``props`` added."""
    return dataclasses.replace(world, props=tuple(world.props) + tuple(props))


def _ball(world: World, marker: str, t: float) -> tuple[np.ndarray, float]:
    for rname, wr in world.robots.items():
        m = wr.robot.markers.get(marker)
        if m is not None:
            return world.pose(rname, t).apply(m.position), ball_radius(m)
    raise ObservationError(f"unknown marker {marker!r}")


def _disc_share(a: float, b: float) -> float:
    """Share of the unit disc's area between the lines x = a and x = b (a < b)."""
    def F(x: float) -> float:
        x = min(max(x, -1.0), 1.0)
        return x * math.sqrt(1.0 - x * x) + math.asin(x)
    return (F(b) - F(a)) / math.pi


def hidden_share(offset: float, half_width: float) -> float:
    """Share of a disc of unit radius hidden by a straight band ``offset +- half_width`` (in disc radii)."""
    return _disc_share(offset - half_width, offset + half_width)


def occluder(world: World, observer: str, marker: str, share: float, kind: str = "pole", *,
             t: float = 0.0, gap: float = 0.08, side: float = 1.0, tilt_deg: float = 35.0,
             color: tuple[int, int, int] = (70, 70, 75)) -> Prop:
    """A prop hiding about ``share`` (0..1) of ball ``marker``'s image as ``observer`` sees it at ``t``.

    ``kind``: ``"pole"`` (vertical, 2 cm thick), ``"cable"`` (8 mm,
    ``tilt_deg`` off vertical) or ``"box"`` (a box whose vertical edge
    crosses the ball).  A pole or cable too thin to hide ``share`` even
    across the middle of the ball is made thicker.  The prop stands ``gap`` metres in front of the ball
    (towards the camera); ``side`` (+-1) picks which side of the ball it
    comes from.  The share is that of a flat disc and the prop's nearest
    point; :func:`~mutloc.sim.render.ball_visibility` measures the truth.
    """
    if kind not in OCCLUDERS:
        raise InputError(f"unknown occluder {kind!r} (one of {', '.join(OCCLUDERS)})")
    if not 0.0 < share < 1.0:
        raise InputError(f"share must be in (0, 1), got {share!r}")
    B, r = _ball(world, marker, t)
    C = world.camera_pose(observer, t).t
    D = float(np.linalg.norm(B - C))
    u = (B - C) / D
    s = D - gap - r
    if s <= 0.05:
        raise InputError(f"the ball is too close to the camera for a gap of {gap} m")
    up = np.array([0.0, 0.0, 1.0])
    if kind == "cable":
        a = math.radians(tilt_deg)
        side_dir = np.cross(u, up)
        side_dir /= np.linalg.norm(side_dir)
        axis = math.cos(a) * up + math.sin(a) * side_dir
    else:
        axis = up
    axis = axis - (axis @ u) * u
    axis /= np.linalg.norm(axis)
    e = np.cross(u, axis)  # across the occluder, in the image plane
    alpha = math.asin(min(1.0, r / D))  # the ball's angular radius
    if kind == "box":
        half_w = math.inf
        thick = 0.0
    else:
        thick = 0.01 if kind == "pole" else 0.004
        half_w = thick / s / alpha
        while hidden_share(0.0, half_w) < min(0.98, share + 0.1):
            half_w *= 1.1
        thick = half_w * s * alpha
    # Offset of the occluder's centre line (in ball radii) hiding `share`.
    lo, hi = -1.0 - (half_w if math.isfinite(half_w) else 0.0), 1.0 + (half_w if math.isfinite(half_w) else 0.0)
    if math.isfinite(half_w):
        lo = 0.0  # the band's share falls as it moves off-centre
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        got = hidden_share(mid, half_w) if math.isfinite(half_w) else _disc_share(mid, 1.0)
        if got > share:
            lo = mid
        else:
            hi = mid
    x = 0.5 * (lo + hi) * alpha * s * float(np.sign(side) or 1.0)
    P = C + s * u + x * e
    if kind != "box":
        return Prop("pole", tuple(P), (thick, 1.2), tuple(axis), color)
    # The box lies beyond its edge line, away from the ball's centre.
    half = np.array([0.05, 0.03, 0.3])
    sgn = float(np.sign(side) or 1.0)
    centre = P + sgn * half[0] * e + half[1] * u
    R = np.column_stack([e, u, np.cross(e, u)])
    rvec = cv2.Rodrigues(R)[0].ravel()
    return Prop("box", tuple(centre), tuple(half), tuple(rvec), color)


def same_hue_clutter(world: World, observer: str, marker: str, *, t: float = 0.0, seed: int = 0,
                     n: int = 2) -> tuple[Prop, ...]:
    """``n`` boxes of ball ``marker``'s colour beside and behind it as ``observer`` sees it (not hiding it).

    Flat boxes of a few centimetres: the colour of the ball, the shape of
    a sticker, a toy brick or a printed panel.
    """
    B, r = _ball(world, marker, t)
    col = next(wr.robot.markers[marker].color for wr in world.robots.values() if marker in wr.robot.markers)
    if col is None:
        raise InputError(f"marker {marker!r} has no colour")
    C = world.camera_pose(observer, t).t
    u = (B - C) / np.linalg.norm(B - C)
    up = np.array([0.0, 0.0, 1.0])
    e = np.cross(u, up)
    e /= np.linalg.norm(e)
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 4242])
    out = []
    for i in range(n):
        sgn = 1.0 if i % 2 == 0 else -1.0
        centre = B + u * rng.uniform(0.4, 0.9) + e * sgn * rng.uniform(0.35, 0.6) + up * rng.uniform(-0.15, 0.1)
        half = (rng.uniform(0.03, 0.07), rng.uniform(0.005, 0.02), rng.uniform(0.02, 0.05))
        rvec = (0.0, 0.0, float(rng.uniform(-0.5, 0.5)))
        out.append(Prop("box", tuple(centre), half, rvec, tuple(int(c) for c in col)))
    return tuple(out)
