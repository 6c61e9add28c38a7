"""A small CPU ray caster for synthetic images with exact ground truth.

No Blender, no GPU: every pixel's ray comes from the camera model itself,
*including lens distortion* (the unit bearing of each pixel centre is the
inverse of :meth:`Camera.project`, computed once per camera and cached), so
a rendered point lands exactly where :meth:`Camera.project` (and
``cv2.projectPoints``) puts it.  Rays are intersected with the room's planes,
spheres (balls, lights), boxes (robot bodies), cylinders and tag cards in a
Numba kernel; shading is Lambert + ambient in linear light, encoded sRGB.

Anti-aliasing: a first pass casts one ray per pixel centre and records what
it hit (object and texture cell); pixels whose 8 neighbours hit something
else, plus the whole neighbourhood of spheres smaller than a few pixels, are
re-cast with 4x4 sub-pixel rays.  Silhouettes and tag edges therefore carry
the exact area coverage to 1/16 of a pixel, so a ball's intensity centroid is
sub-pixel accurate.

Public API: :func:`render`, :func:`project_markers`, :func:`relative_pose`,
:func:`two_robot_world`, :func:`moving_world`.  The scene itself is described
in :mod:`mutloc.sim.world`.
"""

from __future__ import annotations

import math
import zlib
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

import cv2
import numba
import numpy as np

from ..core.camera import Camera, undistort_kernel
from ..core.geometry import so3_exp
from ..core.pose import Pose
from ..core.rig import Rig
from ..errors import InputError, ObservationError
from .synthetic import looking_pose
from .world import (
    LIGHT_EMISSION,
    Prop,
    Room,
    World,
    WorldRobot,
    ball_radius,
    camera_to_world_facing,
    cylinder_spec,
    cylinder_up,
    light_is_on,
    room_textures,
    tag_image,
    tag_scale,
    tag_spec,
)

__all__ = [
    "CAMERA_HEIGHT",
    "SUPERSAMPLE",
    "ball_visibility",
    "default_path",
    "pixel_bearings",
    "render_linear",
    "room_around",
    "scene_primitives",
    "linear_to_srgb",
    "moving_world",
    "project_markers",
    "relative_pose",
    "render",
    "srgb_to_linear",
    "surface_distance",
    "true_observations",
    "two_robot_world",
    "body_box",
    "BODY_BOX",
]

# Sub-pixel rays per axis on edge pixels.
SUPERSAMPLE = 4
# Spheres whose image radius is below this (px) get their whole neighbourhood
# supersampled: a sliver thinner than a pixel can fall between pixel centres.
_SMALL_SPHERE_PX = 4.0
_EPS = 1e-9
_NF = 24  # floats per primitive
_SPHERE, _QUAD, _BOX, _CYL = 0, 1, 2, 3
_KEY_STRIDE = 65536  # key = primitive * stride + texture cell / band
# Robot body (robot camera frame, metres): below and behind the camera.
_BODY_HALF_WIDTH = 0.12
_BODY_TOP = 0.06
_BODY_Z = (-0.30, -0.02)
_HOUSING = ((-0.04, 0.04), (-0.03, 0.03), (-0.07, -0.005))
#: Body of a robot with several cameras (its base_link frame: x forward, y left, z up), before
#: :func:`body_box` cuts it clear of the cameras and markers: (lo, hi) corners, metres.
BODY_BOX = ((-0.20, -0.15, 0.02), (0.20, 0.15, 0.36))


# ---------------------------------------------------------------------------
# colour
# ---------------------------------------------------------------------------


def srgb_to_linear(c: Any) -> np.ndarray:
    """sRGB in [0, 1] -> linear (IEC 61966-2-1)."""
    c = np.asarray(c, dtype=float)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(x: Any) -> np.ndarray:
    """Linear in [0, 1] -> sRGB (IEC 61966-2-1)."""
    x = np.clip(np.asarray(x, dtype=float), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1.0 / 2.4) - 0.055)


def _lin_bgr(rgb255: Any) -> np.ndarray:
    """Linear BGR of an sRGB (r, g, b) 0-255 colour (the renderer works in BGR)."""
    r, g, b = (float(c) for c in rgb255)
    return srgb_to_linear(np.array([b, g, r]) / 255.0)


_LUT = srgb_to_linear(np.arange(256) / 255.0)
# 255 * srgb(x) on a uniform grid (see _encode); the linear segment near 0 is
# 0.0031308 wide, i.e. 51 grid steps, so the interpolation is exact there.
_ENC = 255.0 * linear_to_srgb(np.linspace(0.0, 1.0, 16385))


# ---------------------------------------------------------------------------
# numba kernels
# ---------------------------------------------------------------------------


@numba.njit(cache=True, inline="always")
def _intersect(pf, pi, k, ox, oy, oz, dx, dy, dz):
    """Distance along the unit ray to primitive ``k`` (inf if missed)."""
    typ = pi[k, 0]
    if typ == 0:  # sphere
        ocx = ox - pf[k, 0]
        ocy = oy - pf[k, 1]
        ocz = oz - pf[k, 2]
        b = ocx * dx + ocy * dy + ocz * dz
        c = ocx * ocx + ocy * ocy + ocz * ocz - pf[k, 3] * pf[k, 3]
        disc = b * b - c
        if disc < 0.0:
            return np.inf
        s = math.sqrt(disc)
        t = -b - s
        if t > 1e-9:
            return t
        t = -b + s
        if t > 1e-9:
            return t
        return np.inf
    if typ == 1:  # quad: centre, u, v, normal, half sizes
        den = dx * pf[k, 9] + dy * pf[k, 10] + dz * pf[k, 11]
        if abs(den) < 1e-15:
            return np.inf
        t = ((pf[k, 0] - ox) * pf[k, 9] + (pf[k, 1] - oy) * pf[k, 10] + (pf[k, 2] - oz) * pf[k, 11]) / den
        if not (t > 1e-9):
            return np.inf
        qx = ox + t * dx - pf[k, 0]
        qy = oy + t * dy - pf[k, 1]
        qz = oz + t * dz - pf[k, 2]
        if abs(qx * pf[k, 3] + qy * pf[k, 4] + qz * pf[k, 5]) > pf[k, 12]:
            return np.inf
        if abs(qx * pf[k, 6] + qy * pf[k, 7] + qz * pf[k, 8]) > pf[k, 13]:
            return np.inf
        return t
    if typ == 2:  # oriented box: centre, R (row-major, columns = box axes), half extents
        ocx = ox - pf[k, 0]
        ocy = oy - pf[k, 1]
        ocz = oz - pf[k, 2]
        tmin = -np.inf
        tmax = np.inf
        for a in range(3):
            # Components along box axis a (column a of R).
            ol = ocx * pf[k, 3 + a] + ocy * pf[k, 6 + a] + ocz * pf[k, 9 + a]
            dl = dx * pf[k, 3 + a] + dy * pf[k, 6 + a] + dz * pf[k, 9 + a]
            h = pf[k, 12 + a]
            if abs(dl) < 1e-15:
                if abs(ol) > h:
                    return np.inf
                continue
            t1 = (-h - ol) / dl
            t2 = (h - ol) / dl
            if t1 > t2:
                t1, t2 = t2, t1
            tmin = max(tmin, t1)
            tmax = min(tmax, t2)
        if tmax < tmin or tmax <= 1e-9:
            return np.inf
        return tmin if tmin > 1e-9 else tmax
    # cylinder: centre, axis (unit), radius, half height
    ocx = ox - pf[k, 0]
    ocy = oy - pf[k, 1]
    ocz = oz - pf[k, 2]
    ax = pf[k, 3]
    ay = pf[k, 4]
    az = pf[k, 5]
    r = pf[k, 6]
    h = pf[k, 7]
    oa = ocx * ax + ocy * ay + ocz * az
    da = dx * ax + dy * ay + dz * az
    opx = ocx - oa * ax
    opy = ocy - oa * ay
    opz = ocz - oa * az
    dpx = dx - da * ax
    dpy = dy - da * ay
    dpz = dz - da * az
    best = np.inf
    A = dpx * dpx + dpy * dpy + dpz * dpz
    if A > 1e-18:
        B = opx * dpx + opy * dpy + opz * dpz
        C = opx * opx + opy * opy + opz * opz - r * r
        disc = B * B - A * C
        if disc >= 0.0:
            s = math.sqrt(disc)
            t = (-B - s) / A
            if t > 1e-9 and abs(oa + t * da) <= h:
                best = t
            else:
                t = (-B + s) / A
                if t > 1e-9 and abs(oa + t * da) <= h:
                    best = t
    if abs(da) > 1e-15:
        for sgn in (-1.0, 1.0):
            t = (sgn * h - oa) / da
            if t > 1e-9 and t < best:
                qx = opx + t * dpx
                qy = opy + t * dpy
                qz = opz + t * dpz
                if qx * qx + qy * qy + qz * qz <= r * r:
                    best = t
    return best


@numba.njit(cache=True, inline="always")
def _trace(pf, pi, gf, gi, rb, ox, oy, oz, dx, dy, dz):
    """(distance, primitive) of the nearest hit, (inf, -1) if none.

    ``rb`` = (xmin, xmax, ymin, ymax, zmin, zmax, mode): with mode 1 the ray
    starts inside the room box, whose six walls are primitives 0..5 (floor,
    ceiling, x+, x-, y+, y-), and the wall it leaves through is found with
    three divisions instead of six quad tests; with mode 0 primitives
    ``0 .. rb[7]-1`` are the room's quads, tested one by one.
    """
    best = np.inf
    bk = -1
    if rb[6] > 0.0:
        if dx > 0.0:
            best = (rb[1] - ox) / dx
            bk = 2
        elif dx < 0.0:
            best = (rb[0] - ox) / dx
            bk = 3
        if dy > 0.0:
            t = (rb[3] - oy) / dy
            if t < best:
                best = t
                bk = 4
        elif dy < 0.0:
            t = (rb[2] - oy) / dy
            if t < best:
                best = t
                bk = 5
        if dz > 0.0:
            t = (rb[5] - oz) / dz
            if t < best:
                best = t
                bk = 1
        elif dz < 0.0:
            t = (rb[4] - oz) / dz
            if t < best:
                best = t
                bk = 0
    # Candidate ranges: g = -1 is the room's quads (unless handled above),
    # g >= 0 robot g, skipped unless the ray meets its bounding sphere before
    # the current hit.  One call site keeps the inlined kernel small.
    for g in range(-1, gf.shape[0]):
        if g < 0:
            if rb[6] > 0.0:
                continue
            k0 = 0
            k1 = int(rb[7])
        else:
            ocx = ox - gf[g, 0]
            ocy = oy - gf[g, 1]
            ocz = oz - gf[g, 2]
            b = ocx * dx + ocy * dy + ocz * dz
            c = ocx * ocx + ocy * ocy + ocz * ocz - gf[g, 3] * gf[g, 3]
            disc = b * b - c
            if disc < 0.0:
                continue
            s = math.sqrt(disc)
            if -b + s <= 1e-9 or -b - s >= best:
                continue
            k0 = gi[g, 0]
            k1 = gi[g, 1]
        for k in range(k0, k1):
            t = _intersect(pf, pi, k, ox, oy, oz, dx, dy, dz)
            if t < best:
                best = t
                bk = k
    return best, bk


@numba.njit(cache=True, inline="always")
def _texel(tex, tinfo, lut, tid, x, y, c):
    """Linear value of channel ``c`` of texel (x, y) (in range) of texture entry ``tid``."""
    return lut[tex[tinfo[tid, 0] + (y * tinfo[tid, 1] + x) * 3 + c]]


@numba.njit(cache=True, inline="always")
def _bilinear(tex, tinfo, lut, e, x, y):
    """Bilinear linear-light BGR at continuous texel position (x, y), wrapping around."""
    w = tinfo[e, 1]
    h = tinfo[e, 2]
    x0f = math.floor(x)
    y0f = math.floor(y)
    fx = x - x0f
    fy = y - y0f
    x0 = int(x0f) % w
    y0 = int(y0f) % h
    x1 = x0 + 1
    if x1 == w:
        x1 = 0
    y1 = y0 + 1
    if y1 == h:
        y1 = 0
    base = tinfo[e, 0]
    i00 = base + (y0 * w + x0) * 3
    i10 = base + (y0 * w + x1) * 3
    i01 = base + (y1 * w + x0) * 3
    i11 = base + (y1 * w + x1) * 3
    w00 = (1.0 - fx) * (1.0 - fy)
    w10 = fx * (1.0 - fy)
    w01 = (1.0 - fx) * fy
    w11 = fx * fy
    b = w00 * lut[tex[i00]] + w10 * lut[tex[i10]] + w01 * lut[tex[i01]] + w11 * lut[tex[i11]]
    g = w00 * lut[tex[i00 + 1]] + w10 * lut[tex[i10 + 1]] + w01 * lut[tex[i01 + 1]] + w11 * lut[tex[i11 + 1]]
    r = w00 * lut[tex[i00 + 2]] + w10 * lut[tex[i10 + 2]] + w01 * lut[tex[i01 + 2]] + w11 * lut[tex[i11 + 2]]
    return b, g, r


@numba.njit(cache=True, inline="always")
def _shade(pf, pi, gf, gi, rb, codes, tex, tinfo, lut, lp, k, t, ox, oy, oz, dx, dy, dz, pix_angle):
    """Linear BGR radiance, linear BGR emission and texture sub-key of a hit.

    ``lp`` = (light x, y, z, intensity, ambient, colour b, g, r, shadows);
    with shadows on, a ray towards the light decides whether it reaches the
    hit (hard shadows of a point source).
    """
    typ = pi[k, 0]
    hx = ox + t * dx
    hy = oy + t * dy
    hz = oz + t * dz
    a0 = 0.0
    a1 = 0.0
    a2 = 0.0
    spec = 0.0
    shin = 1.0
    sub = 0
    if typ == 0:
        nx = (hx - pf[k, 0]) / pf[k, 3]
        ny = (hy - pf[k, 1]) / pf[k, 3]
        nz = (hz - pf[k, 2]) / pf[k, 3]
        if pf[k, 7] + pf[k, 8] + pf[k, 9] > 0.0:  # a lit light: emission only
            return pf[k, 7], pf[k, 8], pf[k, 9], pf[k, 7], pf[k, 8], pf[k, 9], 0
        a0 = pf[k, 4]
        a1 = pf[k, 5]
        a2 = pf[k, 6]
        spec = pf[k, 10]
        shin = pf[k, 11]
    elif typ == 1:
        nx = pf[k, 9]
        ny = pf[k, 10]
        nz = pf[k, 11]
        front = dx * nx + dy * ny + dz * nz < 0.0
        tid = pi[k, 1]
        if front and tid >= 0:
            qx = hx - pf[k, 0]
            qy = hy - pf[k, 1]
            qz = hz - pf[k, 2]
            a = qx * pf[k, 3] + qy * pf[k, 4] + qz * pf[k, 5]
            b = qx * pf[k, 6] + qy * pf[k, 7] + qz * pf[k, 8]
            if pi[k, 2] == 1:
                # Printed tag: nearest cell, exact cell edges (anti-aliased by supersampling).
                n = tinfo[tid, 1]
                col = int((a + pf[k, 12]) / (2.0 * pf[k, 12]) * n)
                row = int((pf[k, 13] - b) / (2.0 * pf[k, 13]) * n)
                col = min(max(col, 0), n - 1)
                row = min(max(row, 0), n - 1)
                a0 = pf[k, 14] * _texel(tex, tinfo, lut, tid, col, row, 0)
                a1 = pf[k, 15] * _texel(tex, tinfo, lut, tid, col, row, 1)
                a2 = pf[k, 16] * _texel(tex, tinfo, lut, tid, col, row, 2)
                sub = 1 + row * n + col
            else:
                # Room surface: bilinear from the mip level matching the pixel footprint.
                cosi = abs(dx * nx + dy * ny + dz * nz)
                foot = t * pix_angle / math.sqrt(max(cosi, 0.05))
                ratio = foot / pf[k, 17]
                lev = 0
                if ratio > 1.0:
                    lev = int(math.log2(ratio) + 0.5)
                lev = min(lev, tinfo[tid, 3] - 1)
                e = tid + lev
                sx = tinfo[e, 1] / tinfo[tid, 1]
                sy = tinfo[e, 2] / tinfo[tid, 2]
                x = (a + pf[k, 12]) / pf[k, 17] * sx - 0.5
                y = (pf[k, 13] - b) / pf[k, 17] * sy - 0.5
                t0, t1, t2 = _bilinear(tex, tinfo, lut, e, x, y)
                a0 = pf[k, 14] * t0
                a1 = pf[k, 15] * t1
                a2 = pf[k, 16] * t2
        elif front:
            a0 = pf[k, 14]
            a1 = pf[k, 15]
            a2 = pf[k, 16]
        else:
            a0 = pf[k, 18]
            a1 = pf[k, 19]
            a2 = pf[k, 20]
            sub = 1
    elif typ == 2:
        qx = hx - pf[k, 0]
        qy = hy - pf[k, 1]
        qz = hz - pf[k, 2]
        best = -1.0
        nx = 0.0
        ny = 0.0
        nz = 0.0
        for ax in range(3):
            ol = (qx * pf[k, 3 + ax] + qy * pf[k, 6 + ax] + qz * pf[k, 9 + ax]) / pf[k, 12 + ax]
            if abs(ol) > best:
                best = abs(ol)
                sg = 1.0 if ol > 0.0 else -1.0
                nx = sg * pf[k, 3 + ax]
                ny = sg * pf[k, 6 + ax]
                nz = sg * pf[k, 9 + ax]
                sub = ax
        a0 = pf[k, 15]
        a1 = pf[k, 16]
        a2 = pf[k, 17]
    else:
        qx = hx - pf[k, 0]
        qy = hy - pf[k, 1]
        qz = hz - pf[k, 2]
        s = qx * pf[k, 3] + qy * pf[k, 4] + qz * pf[k, 5]
        rx = qx - s * pf[k, 3]
        ry = qy - s * pf[k, 4]
        rz = qz - s * pf[k, 5]
        rr = math.sqrt(rx * rx + ry * ry + rz * rz)
        h = pf[k, 7]
        if abs(rr - pf[k, 6]) <= abs(abs(s) - h):  # side
            nx = rx / rr
            ny = ry / rr
            nz = rz / rr
            nb = pi[k, 2]
            band = int((h - s) / (2.0 * h) * nb)
            band = min(max(band, 0), nb - 1)
            sub = 1 + band
            if codes[pi[k, 1] + band] != 0:
                a0 = pf[k, 8]
                a1 = pf[k, 9]
                a2 = pf[k, 10]
            else:
                a0 = pf[k, 11]
                a1 = pf[k, 12]
                a2 = pf[k, 13]
        else:  # cap
            sg = 1.0 if s > 0.0 else -1.0
            nx = sg * pf[k, 3]
            ny = sg * pf[k, 4]
            nz = sg * pf[k, 5]
            a0 = pf[k, 14]
            a1 = pf[k, 15]
            a2 = pf[k, 16]
    # Lambert + ambient, normal turned towards the viewer.
    if nx * dx + ny * dy + nz * dz > 0.0:
        nx = -nx
        ny = -ny
        nz = -nz
    lx = lp[0] - hx
    ly = lp[1] - hy
    lz = lp[2] - hz
    ln = math.sqrt(lx * lx + ly * ly + lz * lz)
    ndl = 0.0
    if ln > 0.0:
        ndl = max(0.0, (nx * lx + ny * ly + nz * lz) / ln)
    if ndl > 0.0 and lp[8] > 0.0:
        # Shadow ray, started a hair off the surface towards the light.
        lx /= ln
        ly /= ln
        lz /= ln
        e = 1e-6
        ts, ks = _trace(pf, pi, gf, gi, rb, hx + e * nx, hy + e * ny, hz + e * nz, lx, ly, lz)
        if ks >= 0 and ts < ln - 2e-6:
            ndl = 0.0
        lx *= ln
        ly *= ln
        lz *= ln
    s = lp[4] + lp[3] * ndl
    r0 = a0 * s * lp[5]
    r1 = a1 * s * lp[6]
    r2 = a2 * s * lp[7]
    if spec > 0.0 and ndl > 0.0:
        # Blinn-Phong: half vector of the directions to the light and to the eye.
        hx_ = lx / ln - dx
        hy_ = ly / ln - dy
        hz_ = lz / ln - dz
        hn = math.sqrt(hx_ * hx_ + hy_ * hy_ + hz_ * hz_)
        if hn > 0.0:
            ndh = max(0.0, (nx * hx_ + ny * hy_ + nz * hz_) / hn)
            hl = spec * lp[3] * ndh**shin
            r0 += hl * lp[5]
            r1 += hl * lp[6]
            r2 += hl * lp[7]
    return r0, r1, r2, 0.0, 0.0, 0.0, sub


@numba.njit(cache=True)
def _cast(bear, R, o, pf, pi, gf, gi, rb, codes, tex, tinfo, lut, lp, bg, pix_angle, rgb, emit, key):
    """Cast rays from ``o`` along unit camera-frame bearings ``bear`` (n, 3) turned by ``R`` (camera -> world).

    Fills radiance ``rgb`` (n, 3), emission ``emit`` (n, 3) and ``key`` (n,):
    primitive * 65536 + texture cell, -1 for no hit, -2 for a NaN direction
    (a pixel beyond the lens model's domain: black).  This is the only kernel
    that inlines the intersection and shading code, to keep compile time down.
    """
    for i in range(bear.shape[0]):
        bx = bear[i, 0]
        by = bear[i, 1]
        bz = bear[i, 2]
        if not (math.isfinite(bx) and math.isfinite(by) and math.isfinite(bz)):
            for c in range(3):
                rgb[i, c] = 0.0
                emit[i, c] = 0.0
            key[i] = -2
            continue
        dx = R[0, 0] * bx + R[0, 1] * by + R[0, 2] * bz
        dy = R[1, 0] * bx + R[1, 1] * by + R[1, 2] * bz
        dz = R[2, 0] * bx + R[2, 1] * by + R[2, 2] * bz
        t, k = _trace(pf, pi, gf, gi, rb, o[0], o[1], o[2], dx, dy, dz)
        if k < 0:
            for c in range(3):
                rgb[i, c] = bg[c]
                emit[i, c] = 0.0
            key[i] = -1
            continue
        r0, r1, r2, e0, e1, e2, sub = _shade(pf, pi, gf, gi, rb, codes, tex, tinfo, lut, lp, k, t,
                                             o[0], o[1], o[2], dx, dy, dz, pix_angle)
        rgb[i, 0] = r0
        rgb[i, 1] = r1
        rgb[i, 2] = r2
        emit[i, 0] = e0
        emit[i, 1] = e1
        emit[i, 2] = e2
        key[i] = k * 65536 + sub


@numba.njit(cache=True)
def _edge_pixels(key, force, out):
    """Flat indices of pixels to supersample: a neighbour hit something else, or forced."""
    H = key.shape[0]
    W = key.shape[1]
    n = 0
    for v in range(H):
        for u in range(W):
            k0 = key[v, u]
            edge = force[v, u]
            if not edge:
                for dv in range(-1, 2):
                    vv = v + dv
                    if vv < 0 or vv >= H:
                        continue
                    for du in range(-1, 2):
                        uu = u + du
                        if uu < 0 or uu >= W:
                            continue
                        if key[vv, uu] != k0:
                            edge = True
                            break
                    if edge:
                        break
            if edge:
                out[n] = v * W + u
                n += 1
    return n


@numba.njit(cache=True)
def _subpixel_bearings(idx, ss, W, K, dist, out):
    """Unit bearings of ss x ss sub-pixel points (stratified, N-rooks) in each listed pixel.

    Row ``i * ss * ss + sy * ss + sx`` of ``out`` is sub-point (sx, sy) of
    pixel ``idx[i]``; NaN where the distortion cannot be inverted.
    """
    uv = np.empty(2)
    b = np.empty(3)
    inv = 1.0 / ss
    pinhole = True
    for j in range(dist.shape[0]):
        if dist[j] != 0.0:
            pinhole = False
    r = 0
    for i in range(idx.shape[0]):
        v = idx[i] // W
        u = idx[i] % W
        for sy in range(ss):
            for sx in range(ss):
                # N-rooks pattern inside the ss x ss strata: all ss*ss samples
                # have distinct u and distinct v, so an axis-aligned edge (a
                # tag side) is resolved to 1/ss^2 px, not 1/ss.
                uv[0] = u - 0.5 + (sx + (sy + 0.5) * inv) * inv
                uv[1] = v - 0.5 + (sy + (sx + 0.5) * inv) * inv
                if pinhole:
                    # No distortion: invert K directly (Newton would give the same).
                    yn = (uv[1] - K[1, 2]) / K[1, 1]
                    xn = (uv[0] - K[0, 2] - K[0, 1] * yn) / K[0, 0]
                    nrm = 1.0 / math.sqrt(xn * xn + yn * yn + 1.0)
                    out[r, 0] = xn * nrm
                    out[r, 1] = yn * nrm
                    out[r, 2] = nrm
                else:
                    undistort_kernel(K, dist, uv, b)
                    out[r, 0] = b[0]
                    out[r, 1] = b[1]
                    out[r, 2] = b[2]
                r += 1


@numba.njit(cache=True)
def _encode(rgb, scale, noise, enc, out):
    """uint8 = round(255 * srgb(clip(scale * rgb)) + noise); ``noise`` may be empty.

    ``enc`` tabulates 255 * srgb on a uniform grid over [0, 1]; linear
    interpolation in it is within 0.005 grey levels of the formula.
    """
    H = rgb.shape[0]
    W = rgb.shape[1]
    n = enc.shape[0] - 1
    has_noise = noise.shape[0] == H
    for v in range(H):
        for u in range(W):
            for c in range(3):
                x = rgb[v, u, c] * scale
                if x <= 0.0:
                    y = 0.0
                elif x >= 1.0:
                    y = 255.0
                else:
                    f = x * n
                    i = int(f)
                    if i >= n:
                        i = n - 1
                    f -= i
                    y = enc[i] + f * (enc[i + 1] - enc[i])
                if has_noise:
                    y += noise[v, u, c]
                y = math.floor(y + 0.5)
                out[v, u, c] = 0 if y < 0.0 else (255 if y > 255.0 else int(y))


@numba.njit(cache=True)
def _bearing_grid(K, dist, out):
    """Unit bearing of every pixel centre; NaN where the distortion is not invertible."""
    uv = np.empty(2)
    b = np.empty(3)
    for v in range(out.shape[0]):
        for u in range(out.shape[1]):
            uv[0] = u
            uv[1] = v
            undistort_kernel(K, dist, uv, b)
            out[v, u, 0] = b[0]
            out[v, u, 1] = b[1]
            out[v, u, 2] = b[2]


# ---------------------------------------------------------------------------
# per-camera bearing cache
# ---------------------------------------------------------------------------

_BEARINGS: OrderedDict[tuple, np.ndarray] = OrderedDict()
_BEARINGS_MAX = 6


def _is_wide(camera: Any) -> bool:
    """Whether ``camera`` is a lens model other than the pinhole (no undistort kernel, no culling)."""
    return getattr(camera, "model", "pinhole") != "pinhole"


def _wide_subpixel_bearings(camera: Any, idx: np.ndarray, ss: int, W: int) -> np.ndarray:
    """:func:`_subpixel_bearings` (same sub-pixel pattern, same row order) through any lens."""
    inv = 1.0 / ss
    sy, sx = np.divmod(np.arange(ss * ss), ss)
    du = -0.5 + (sx + (sy + 0.5) * inv) * inv
    dv = -0.5 + (sy + (sx + 0.5) * inv) * inv
    v, u = np.divmod(idx, W)
    uv = np.stack([(u[:, None] + du[None, :]).ravel(), (v[:, None] + dv[None, :]).ravel()], axis=1)
    return np.ascontiguousarray(camera.pixels_to_bearings(uv.astype(float)))


def _camera_size(camera: Camera, observer: str) -> tuple[int, int]:
    if camera.size is None:
        raise InputError(f"robot {observer!r}: camera has no image size: give 'size: [width, height]' in the rig")
    return camera.size


def pixel_bearings(camera: Camera) -> np.ndarray:
    """Unit bearings (H, W, 3) of every pixel centre of ``camera`` (cached, read-only).

    The same inverse as :meth:`Camera.pixels_to_bearings` (its kernel), but
    NaN instead of an error where the distortion cannot be inverted (e.g. the
    corners of a strongly distorted lens): those pixels render black.  Any
    lens (:mod:`mutloc.core.lenses`: fisheye, omni): its own
    ``pixels_to_bearings``, NaN (black) where it images nothing (outside
    the fisheye circle, beyond ``max_angle``).
    """
    if camera.size is None:
        raise InputError("camera has no image size")
    wide = _is_wide(camera)
    key = (camera.K.tobytes(), camera.dist.tobytes(), camera.size) if not wide else \
        ("wide", type(camera).__name__, camera.params, camera.size)
    hit = _BEARINGS.get(key)
    if hit is not None:
        _BEARINGS.move_to_end(key)
        return hit
    w, h = camera.size
    if wide:
        vv, uu = np.mgrid[0:h, 0:w]
        out = camera.pixels_to_bearings(np.column_stack([uu.ravel(), vv.ravel()]).astype(float)).reshape(h, w, 3)
    else:
        out = np.empty((h, w, 3))
        _bearing_grid(camera.K, camera.dist, out)
    out.flags.writeable = False
    _BEARINGS[key] = out
    while len(_BEARINGS) > _BEARINGS_MAX:
        _BEARINGS.popitem(last=False)
    return out


# ---------------------------------------------------------------------------
# compiling a world at time t into flat arrays
# ---------------------------------------------------------------------------


class _Scene:
    """Flat arrays of one world at one instant, as the kernels want them."""

    def __init__(self, T_cw: Pose | None = None) -> None:
        # Primitives wholly behind this camera's image plane are left out: no
        # ray of the camera (bearing z > 0) can reach them.
        self.T_cw = T_cw
        self.rows: list[np.ndarray] = []
        self.ints: list[tuple[int, int, int]] = []
        self.owner: list[tuple[str, str | None]] = []  # (robot or "", marker or None)
        self.bound: list[tuple[np.ndarray, float]] = []
        self.codes: list[int] = []
        self.groups: list[tuple[int, int]] = []
        self.n_room = 0
        self.box: tuple[float, ...] | None = None  # room (xmin, xmax, ymin, ymax, zmin, zmax)

    def add(self, row: np.ndarray, ints: tuple[int, int, int], owner: tuple[str, str | None],
            centre: np.ndarray, radius: float) -> None:
        # Room walls are never culled: _trace finds them by index (0..5).
        if owner[0] and self.T_cw is not None and float(self.T_cw.apply(centre)[2]) + radius <= 1e-9:
            return
        r = np.zeros(_NF)
        r[: row.size] = row
        self.rows.append(r)
        self.ints.append(ints)
        self.owner.append(owner)
        self.bound.append((np.asarray(centre, float), float(radius)))

    def finish(self) -> None:
        n = len(self.rows)
        self.pf = np.ascontiguousarray(np.array(self.rows).reshape(n, _NF))
        self.pi = np.ascontiguousarray(np.array(self.ints, dtype=np.int64).reshape(n, 3))
        gf = np.zeros((len(self.groups), 4))
        for g, (a, b) in enumerate(self.groups):
            cs = np.array([self.bound[k][0] for k in range(a, b)])
            c = cs.mean(axis=0)
            rad = max(np.linalg.norm(self.bound[k][0] - c) + self.bound[k][1] for k in range(a, b))
            gf[g, :3] = c
            gf[g, 3] = rad * (1.0 + 1e-9) + 1e-9
        self.gf = gf
        self.gi = np.array(self.groups, dtype=np.int64).reshape(-1, 2)
        self.codes_arr = np.array(self.codes if self.codes else [0], dtype=np.int64)

    def room_box(self, origin: np.ndarray) -> np.ndarray:
        """The kernels' ``rb`` for rays from ``origin`` (see :func:`_trace`)."""
        rb = np.zeros(8)
        rb[7] = self.n_room
        if self.box is not None:
            rb[:6] = self.box
            inside = all(self.box[2 * a] < origin[a] < self.box[2 * a + 1] for a in range(3))
            rb[6] = 1.0 if inside else 0.0
        return rb


def _quad_row(c: np.ndarray, u: np.ndarray, v: np.ndarray, hu: float, hv: float, albedo: np.ndarray,
              texel: float = 0.0, back: np.ndarray | None = None) -> np.ndarray:
    n = np.cross(u, v)
    back = albedo if back is None else back
    return np.concatenate([c, u, v, n, [hu, hv], albedo, [texel], back])


def _box_row(c: np.ndarray, R: np.ndarray, half: np.ndarray, albedo: np.ndarray) -> np.ndarray:
    return np.concatenate([c, R.reshape(-1), half, albedo])


_ATLASES: OrderedDict[tuple, tuple[np.ndarray, np.ndarray, dict[Any, int]]] = OrderedDict()


def _atlas(world: World) -> tuple[np.ndarray, np.ndarray, dict[Any, int]]:
    """Every texture of ``world`` in one flat uint8 buffer (cached on room and tags).

    Rows of ``tinfo``: (offset, width, height, levels); a mip-mapped texture's
    levels follow its base row.
    """
    tags = []
    for wr in world.robots.values():
        for m in wr.robot.markers.values():
            if m.kind == "tag":
                fam, tid, _, _ = tag_spec(m)
                tags.append((fam, tid))
    room = world.room
    key = (None if room is None else (tuple(room.size), room.height, room.seed, room.texel, room.floor_decals,
                                  room.poster_text),
           tuple(sorted(set(tags))))
    cached = _ATLASES.get(key)
    if cached is not None:
        _ATLASES.move_to_end(key)
        return cached
    chunks: list[np.ndarray] = []
    info: list[list[int]] = []
    ids: dict[Any, int] = {}
    offset = 0

    def push(img: np.ndarray, levels: int) -> None:
        nonlocal offset
        img = np.ascontiguousarray(img, dtype=np.uint8)
        if img.ndim == 2:
            img = np.repeat(img[:, :, None], 3, axis=2)
        h, w = img.shape[:2]
        info.append([offset, w, h, levels])
        chunks.append(img.reshape(-1))
        offset += img.size

    if world.room is not None:
        for name, img in room_textures(world.room).items():
            ids[("room", name)] = len(info)
            levels = [img]
            while min(levels[-1].shape[:2]) >= 16 and len(levels) < 10:
                prev = levels[-1]
                levels.append(cv2.resize(prev, ((prev.shape[1] + 1) // 2, (prev.shape[0] + 1) // 2),
                                         interpolation=cv2.INTER_AREA))
            for lv in levels:
                push(lv, len(levels))
    for fam, tid in sorted(set(tags)):
        ids[("tag", fam, tid)] = len(info)
        push(tag_image(fam, tid), 1)
    tex = np.concatenate(chunks) if chunks else np.zeros(3, np.uint8)
    tinfo = np.array(info, dtype=np.int64).reshape(-1, 4) if info else np.zeros((1, 4), np.int64)
    out = (tex, tinfo, ids)
    _ATLASES[key] = out
    while len(_ATLASES) > 4:
        _ATLASES.popitem(last=False)
    return out


def _marker_extent(m: Any) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box (lo, hi) of a marker in its robot frame."""
    kind = m.kind
    if kind == "tag":
        fam, tid, size, _R = tag_spec(m)
        e = 0.5 * size * tag_scale(fam, tid) * math.sqrt(2.0)
    elif kind == "cylinder":
        r, h, _ = cylinder_spec(m)
        e = math.hypot(r, 0.5 * h)
    else:
        e = ball_radius(m)
    return m.position - e, m.position + e


def _body_marker_extent(m: Any) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_marker_extent`, but a tag's is its card's (a flat square, white margin included): a tag
    printed on a body's side, just proud of it, does not cut the body back."""
    if m.kind != "tag":
        return _marker_extent(m)
    fam, tid, size, Rt = tag_spec(m)
    half = 0.5 * size * tag_scale(fam, tid)
    corners = m.position + np.array([[a, b, 0.0] for a in (-half, half) for b in (-half, half)]) @ Rt.T
    return corners.min(axis=0), corners.max(axis=0)


def _overlaps(lo: np.ndarray, hi: np.ndarray, lo2: np.ndarray, hi2: np.ndarray) -> bool:
    return bool(np.all(lo < hi2) and np.all(lo2 < hi))


def body_box(robot: Any, *, margin: float = 0.01) -> tuple[np.ndarray, np.ndarray] | None:
    """The grey box drawn for a robot with several cameras: ``(lo, hi)`` corners in its body frame, or None.

    The body frame is taken to be a ``base_link`` (x forward, y left, z up,
    origin on the floor): the box is :data:`BODY_BOX` (40 x 30 cm, 2 to
    36 cm above the floor), then cut back so that every camera is outside it
    (the face its optical axis points through moves ``margin`` behind the
    camera: a camera on the body's surface sees out, never the inside of the
    box) and no marker is swallowed (the face needing the least cut moves
    clear of it).  None when nothing sensible is left.
    """
    lo = np.array(BODY_BOX[0], float)
    hi = np.array(BODY_BOX[1], float)
    for mount in robot.mounts.values():
        c = np.asarray(mount.pose.t, float)
        if not (np.all(c > lo - margin) and np.all(c < hi + margin)):
            continue
        axis = mount.pose.R[:, 2]
        a = int(np.argmax(np.abs(axis)))
        if axis[a] > 0:
            hi[a] = min(hi[a], c[a] - margin)
        else:
            lo[a] = max(lo[a], c[a] + margin)
    for m in robot.markers.values():
        mlo, mhi = _body_marker_extent(m)
        if not _overlaps(lo, hi, mlo - margin, mhi + margin):
            continue
        # cut the face that needs the least cut
        cuts = [(hi[a] - (mlo[a] - margin), a, 1) for a in range(3)] + \
               [((mhi[a] + margin) - lo[a], a, 0) for a in range(3)]
        _, a, top = min(cuts)
        if top:
            hi[a] = mlo[a] - margin
        else:
            lo[a] = mhi[a] + margin
    if np.any(hi - lo < 0.02):
        return None
    return lo, hi


def _add_robot(scene: _Scene, world: World, wr: WorldRobot, T: Pose, atlas_ids: dict[Any, int],
               t_now: float) -> None:
    """Append robot ``wr``'s body and markers at pose ``T`` (camera -> world), time ``t_now``."""
    R, t = T.R, T.t
    name = wr.name
    markers = list(wr.robot.markers.values())
    boxes = [_marker_extent(m) for m in markers]

    if wr.body and wr.robot.is_body:
        box = body_box(wr.robot)
        if box is not None:
            lo, hi = box
            c = 0.5 * (lo + hi)
            half = 0.5 * (hi - lo)
            scene.add(_box_row(R @ c + t, R, half, _lin_bgr(wr.body_color)), (_BOX, -1, 0), (name, None),
                      R @ c + t, float(np.linalg.norm(half)))
    elif wr.body:
        # Height of the camera above the floor along the robot's "down" axis.
        down_z = R[2, 1]
        height = t[2] / -down_z if (world.room is not None and down_z < -0.3) else 0.45
        height = float(np.clip(height, 0.1, 3.0))
        z_back, z_front = _BODY_Z
        lo = np.array([-_BODY_HALF_WIDTH, _BODY_TOP, z_back])
        hi = np.array([_BODY_HALF_WIDTH, height, z_front])
        # Keep the body clear of the markers: move its front behind any it would swallow.
        for mlo, mhi in boxes:
            if _overlaps(lo, hi, mlo, mhi):
                hi[2] = min(hi[2], mlo[2] - 0.005)
        if hi[1] - lo[1] > 0.02 and hi[2] - lo[2] > 0.02:
            c = 0.5 * (lo + hi)
            half = 0.5 * (hi - lo)
            scene.add(_box_row(R @ c + t, R, half, _lin_bgr(wr.body_color)), (_BOX, -1, 0), (name, None),
                      R @ c + t, float(np.linalg.norm(half)))
        hlo = np.array([a for a, _ in _HOUSING])
        hhi = np.array([b for _, b in _HOUSING])
        if not any(_overlaps(hlo, hhi, mlo, mhi) for mlo, mhi in boxes):
            c = 0.5 * (hlo + hhi)
            half = 0.5 * (hhi - hlo)
            scene.add(_box_row(R @ c + t, R, half, _lin_bgr((40, 40, 40))), (_BOX, -1, 0), (name, None),
                      R @ c + t, float(np.linalg.norm(half)))

    for m in markers:
        kind = m.kind
        c = R @ m.position + t
        color = m.color if m.color is not None else (220, 220, 220)
        if kind in ("ball", "point"):  # a marker without a detector is drawn as a grey ball
            r = ball_radius(m)
            fin = world.ball_finish if kind == "ball" else None
            gloss = [fin.specular, fin.shininess] if fin is not None else [0.0, 1.0]
            row = np.concatenate([c, [r], _lin_bgr(color), [0.0, 0.0, 0.0], gloss])
            scene.add(row, (_SPHERE, -1, 0), (name, m.name), c, r)
        elif kind == "light":
            r = ball_radius(m)
            lin = _lin_bgr(m.color if m.color is not None else (255, 255, 255))
            if light_is_on(m, t_now):
                strength = float(m.extra.get("intensity", 1.0))
                emission = LIGHT_EMISSION * strength * lin / max(float(lin.max()), 1e-6)
                albedo = np.zeros(3)
            else:
                # An unlit LED behind a diffuser: dim, slightly tinted.
                emission = np.zeros(3)
                albedo = 0.05 + 0.2 * lin
            scene.add(np.concatenate([c, [r], albedo, emission, [0.0, 1.0]]), (_SPHERE, -1, 0), (name, m.name), c, r)
        elif kind == "tag":
            fam, tid, size, Rt = tag_spec(m)
            half = 0.5 * size * tag_scale(fam, tid)
            u = R @ Rt[:, 0]
            v = -(R @ Rt[:, 1])  # texture "up" is the tag's -y
            row = _quad_row(c, u, v, half, half, np.ones(3), 0.0, _lin_bgr((200, 200, 200)))
            scene.add(row, (_QUAD, atlas_ids[("tag", fam, tid)], 1), (name, m.name), c, half * math.sqrt(2.0))
        else:
            r, h, code = cylinder_spec(m)
            axis = R @ cylinder_up(wr.robot.is_body)  # up: the robot's -y, or +z for a body
            off = len(scene.codes)
            scene.codes.extend(int(b) for b in code)
            row = np.concatenate([c, axis, [r, 0.5 * h], _lin_bgr((30, 30, 30)), _lin_bgr((225, 225, 225)),
                                  _lin_bgr((128, 128, 128))])
            scene.add(row, (_CYL, off, len(code)), (name, m.name), c, math.hypot(r, 0.5 * h))


def _add_prop(scene: _Scene, prop: Prop) -> None:
    """Append a static prop (pole or box, world frame)."""
    c = np.asarray(prop.centre, float)
    col = _lin_bgr(prop.color)
    if prop.kind == "pole":
        r, length = (float(x) for x in prop.size)
        axis = np.asarray(prop.axis, float)
        axis = axis / np.linalg.norm(axis)
        off = len(scene.codes)
        scene.codes.append(1)  # one band, dark = the prop's colour
        row = np.concatenate([c, axis, [r, 0.5 * length], col, col, col])
        scene.add(row, (_CYL, off, 1), ("", "#prop"), c, math.hypot(r, 0.5 * length))
    else:
        half = np.asarray(prop.size, float)
        R = so3_exp(np.asarray(prop.axis, float))
        scene.add(_box_row(c, R, half, col), (_BOX, -1, 0), ("", "#prop"), c, float(np.linalg.norm(half)))


def _compile(world: World, t: float, observer: str | None = None
             ) -> tuple[_Scene, tuple[np.ndarray, np.ndarray, dict[Any, int]]]:
    """The world at time ``t`` as flat arrays (culled for ``observer``'s camera if given and a pinhole:
    nothing behind its image plane)."""
    atlas = _atlas(world)
    ids = atlas[2]
    cull = observer is not None and not _is_wide(world.camera(observer))
    scene = _Scene(world.camera_pose(observer, t).inverse() if cull else None)
    if world.room is not None:
        for name, c, u, v, hu, hv in world.room.surfaces():
            row = _quad_row(c, u, v, hu, hv, np.ones(3), world.room.texel)
            scene.add(row, (_QUAD, ids[("room", name)], 0), ("", None), c, math.hypot(hu, hv))
        scene.n_room = len(scene.rows)
        (cx, cy), (sx, sy) = world.room.center, world.room.size
        scene.box = (cx - sx / 2, cx + sx / 2, cy - sy / 2, cy + sy / 2, 0.0, float(world.room.height))
    for wr in world.robots.values():
        start = len(scene.rows)
        _add_robot(scene, world, wr, wr.pose_at(t), ids, t)
        if len(scene.rows) > start:
            scene.groups.append((start, len(scene.rows)))
    for prop in world.props:
        # One group per prop: its own bounding sphere keeps rays cheap.
        start = len(scene.rows)
        _add_prop(scene, prop)
        if len(scene.rows) > start:
            scene.groups.append((start, len(scene.rows)))
    scene.finish()
    return scene, atlas


# ---------------------------------------------------------------------------
# public API
# ---------------------------------------------------------------------------


def _check_time(t: Any) -> float:
    try:
        tf = float(t)
    except (TypeError, ValueError):
        raise InputError(f"time t must be a number, got {t!r}") from None
    if not math.isfinite(tf):
        raise InputError(f"time t must be finite, got {t!r}")
    return tf


def _seed_for(seed: int, observer: str, t: float) -> np.random.Generator:
    # Independent noise per robot and instant, reproducible from the seed.
    mix = [int(seed) & 0xFFFFFFFF, zlib.crc32(observer.encode()), zlib.crc32(np.float64(t).tobytes())]
    return np.random.default_rng(mix)


def _motion_blur(img: np.ndarray, length: float, angle_deg: float) -> np.ndarray:
    """Linear motion blur of ``length`` px along ``angle_deg`` (box kernel, sub-pixel length)."""
    half = 0.5 * length
    size = 2 * int(math.ceil(half)) + 3
    kern = np.zeros((size, size), np.float32)
    c = size // 2
    ca, sa = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    n = max(8, int(length * 8))
    for s in np.linspace(-half, half, n):
        x, y = c + s * ca, c + s * sa
        x0, y0 = int(math.floor(x)), int(math.floor(y))
        fx, fy = x - x0, y - y0
        kern[y0, x0] += (1 - fx) * (1 - fy)
        kern[y0, x0 + 1] += fx * (1 - fy)
        kern[y0 + 1, x0] += (1 - fx) * fy
        kern[y0 + 1, x0 + 1] += fx * fy
    kern /= kern.sum()
    return cv2.filter2D(img, -1, kern, borderType=cv2.BORDER_REPLICATE)


def _force_small_spheres(scene: _Scene, T_cw: Pose, camera: Camera, force: np.ndarray) -> None:
    """Mark the neighbourhood of spheres too small for the edge test to catch."""
    H, W = force.shape
    fx = camera.K[0, 0]
    wide = _is_wide(camera)
    for k in range(len(scene.rows)):
        if scene.pi[k, 0] != _SPHERE:
            continue
        X = T_cw.apply(scene.pf[k, :3])
        r = scene.pf[k, 3]
        d = float(np.linalg.norm(X))
        if wide:
            # Any lens: the image radius from the projection's Jacobian (its largest stretch).
            if d <= r:
                continue
            uv, J = camera.project_jacobian(X)
            if not (np.all(np.isfinite(uv)) and np.all(np.isfinite(J))):
                continue
            rho = float(np.linalg.svd(J, compute_uv=False)[0]) * d * math.asin(min(1.0, r / d))
            if rho >= _SMALL_SPHERE_PX:
                continue
            m = 1.5 * rho + 2.0
            u0, u1 = int(max(0, math.floor(uv[0] - m))), int(min(W - 1, math.ceil(uv[0] + m)))
            v0, v1 = int(max(0, math.floor(uv[1] - m))), int(min(H - 1, math.ceil(uv[1] + m)))
            if u0 <= u1 and v0 <= v1:
                force[v0:v1 + 1, u0:u1 + 1] = True
            continue
        if X[2] <= r or d <= r:
            continue
        rho = fx * math.asin(min(1.0, r / d)) / max(X[2] / d, 0.1)
        if rho >= _SMALL_SPHERE_PX:
            continue
        uv = camera.project(X)
        if not np.all(np.isfinite(uv)):
            continue
        m = 1.5 * rho + 2.0
        u0, u1 = int(max(0, math.floor(uv[0] - m))), int(min(W - 1, math.ceil(uv[0] + m)))
        v0, v1 = int(max(0, math.floor(uv[1] - m))), int(min(H - 1, math.ceil(uv[1] + m)))
        if u0 <= u1 and v0 <= v1:
            force[v0:v1 + 1, u0:u1 + 1] = True


def _light_params(world: World) -> np.ndarray:
    """The kernels' ``lp``: light position, intensity, ambient, linear BGR colour, shadows flag."""
    lpos = world.light_position()
    li = world.light
    return np.concatenate([lpos, [li.intensity, li.ambient], _lin_bgr(li.color), [1.0 if li.shadows else 0.0]])


def render_linear(world: World, observer: str, t: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Anti-aliased linear-light BGR radiance (H, W, 3) and the lights' emission, before the sensor.

    ``observer``: ``ROBOT`` or ``ROBOT/CAMERA`` (see :func:`render`)."""
    t = _check_time(t)
    camera = world.camera(observer)
    w, h = _camera_size(camera, observer)
    bear = pixel_bearings(camera)
    scene, (tex, tinfo, _ids) = _compile(world, t, observer)
    T_wc = world.camera_pose(observer, t)
    R = np.ascontiguousarray(T_wc.R)
    o = np.ascontiguousarray(T_wc.t)
    lp = _light_params(world)
    bg = _lin_bgr(world.background)
    pix_angle = 1.0 / float(camera.K[0, 0])
    args = (scene.pf, scene.pi, scene.gf, scene.gi, scene.room_box(o), scene.codes_arr, tex, tinfo, _LUT, lp, bg)

    rgb = np.empty((h * w, 3))
    emit = np.empty((h * w, 3))
    key = np.empty(h * w, np.int64)
    _cast(bear.reshape(-1, 3), R, o, *args, pix_angle, rgb, emit, key)

    # Second pass: pixels on an edge (or near a tiny sphere) get ss x ss rays.
    force = np.zeros((h, w), np.bool_)
    _force_small_spheres(scene, T_wc.inverse(), camera, force)
    idx = np.empty(h * w, np.int64)
    n = _edge_pixels(key.reshape(h, w), force, idx)
    idx = idx[:n]
    ss = SUPERSAMPLE
    if n:
        if _is_wide(camera):
            sub_b = _wide_subpixel_bearings(camera, idx, ss, w)
        else:
            sub_b = np.empty((n * ss * ss, 3))
            _subpixel_bearings(idx, ss, w, camera.K, camera.dist, sub_b)
        sub_b.flags.writeable = bool(bear.flags.writeable)  # (as the first pass's: one compiled _cast)
        sub_rgb = np.empty((n * ss * ss, 3))
        sub_emit = np.empty((n * ss * ss, 3))
        sub_key = np.empty(n * ss * ss, np.int64)
        _cast(sub_b, R, o, *args, pix_angle / ss, sub_rgb, sub_emit, sub_key)
        rgb[idx] = sub_rgb.reshape(n, ss * ss, 3).mean(axis=1)
        emit[idx] = sub_emit.reshape(n, ss * ss, 3).mean(axis=1)
    return rgb.reshape(h, w, 3), emit.reshape(h, w, 3)


def render(world: World, observer: str, t: float = 0.0, *, seed: int = 0, noise_sigma: float = 0.0,
           jpeg_quality: int | None = None, blur_px: float = 0.0) -> np.ndarray:
    """What camera ``observer`` sees at time ``t``: uint8 BGR (H, W, 3).

    ``observer`` is an observer key as in observations (SPEC): ``"p"`` for a
    robot with one camera, ``"p/front"`` for camera ``front`` of a robot with
    several cameras, whose pose in the world is ``T_world_robot @
    mount.pose``.  Any lens (pinhole, fisheye, omni): each pixel's ray is the
    lens's own inverse (:func:`pixel_bearings`), and pixels the lens does not
    image (outside a fisheye's circle) are black.

    Pipeline: anti-aliased ray casting (linear light) -> bloom around lit
    lights -> linear motion blur of ``blur_px`` pixels along
    ``world.sensor.blur_angle_deg`` -> optical blur (``sensor.psf_sigma_px``)
    -> ``gain * exposure`` -> sRGB -> additive
    Gaussian noise of ``noise_sigma * gain`` grey levels -> 8 bits -> optional
    JPEG round trip at ``jpeg_quality``.  Deterministic: the same arguments
    give the same image; the noise depends on ``seed``, ``observer`` and ``t``.
    """
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool):
        raise InputError(f"seed must be an integer, got {seed!r}")
    for what, val in (("noise_sigma", noise_sigma), ("blur_px", blur_px)):
        if not (isinstance(val, (int, float, np.integer, np.floating)) and math.isfinite(val) and val >= 0):
            raise InputError(f"{what} must be a finite number >= 0, got {val!r}")
    if jpeg_quality is not None and (isinstance(jpeg_quality, bool) or not isinstance(jpeg_quality, (int, np.integer))
                                     or not 1 <= jpeg_quality <= 100):
        raise InputError(f"jpeg_quality must be an integer in 1..100 or None, got {jpeg_quality!r}")
    rgb, emit = render_linear(world, observer, t)
    sensor = world.sensor
    # The pixels that emit (a few lights), found in one pass over the contiguous array:
    # a reduction over the colour axis took a tenth of a second a frame at 1920x1080.
    lit = np.flatnonzero(emit.reshape(-1) > 0) // 3 if sensor.bloom_strength > 0 and sensor.bloom_sigma_px > 0 \
        else np.empty(0, np.int64)
    if lit.size:
        # Glare around lights: a Gaussian PSF of the emitted light, computed on
        # the lights' neighbourhood only.
        ys, xs = np.divmod(lit, emit.shape[1])
        m = int(math.ceil(4 * sensor.bloom_sigma_px))
        y0, y1 = max(0, ys.min() - m), min(rgb.shape[0], ys.max() + m + 1)
        x0, x1 = max(0, xs.min() - m), min(rgb.shape[1], xs.max() + m + 1)
        glow = cv2.GaussianBlur(emit[y0:y1, x0:x1], (0, 0), sensor.bloom_sigma_px, borderType=cv2.BORDER_CONSTANT)
        rgb[y0:y1, x0:x1] += sensor.bloom_strength * glow
    if blur_px > 0:
        rgb = _motion_blur(rgb, float(blur_px), sensor.blur_angle_deg)
    if sensor.psf_sigma_px > 0:
        rgb = cv2.GaussianBlur(rgb, (0, 0), float(sensor.psf_sigma_px), borderType=cv2.BORDER_REPLICATE)
    h, w = rgb.shape[:2]
    if noise_sigma > 0:
        noise = _seed_for(int(seed), observer, float(t)).standard_normal((h, w, 3)) * (noise_sigma * sensor.gain)
    else:
        noise = np.zeros((0, 0, 3))
    out = np.empty((h, w, 3), np.uint8)
    _encode(np.ascontiguousarray(rgb), float(sensor.exposure * sensor.gain), noise, _ENC, out)
    if jpeg_quality is not None:
        ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
        if not ok:
            raise InputError("JPEG encoding failed")
        out = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    return out


def relative_pose(world: World, source: str, target: str, t: float = 0.0) -> Pose:
    """``T_target_source`` at time ``t``: ``x_target = R @ x_source + t`` (SPEC's T_qp for p=source, q=target),
    between robot frames (body frames for robots with several cameras)."""
    t = _check_time(t)
    return world.pose(target, t).inverse() @ world.pose(source, t)


def _visible_through_lens(camera: Camera, X: np.ndarray, uv: np.ndarray) -> bool:
    """True if pixel ``uv`` really is where ``X`` is seen, not a fold-over of the distortion."""
    if _is_wide(camera):
        b = camera.pixels_to_bearings(np.asarray(uv, float))
        return bool(np.all(np.isfinite(b))) and float(b @ (X / np.linalg.norm(X))) > math.cos(1e-7)
    b = np.empty(3)
    if not undistort_kernel(camera.K, camera.dist, np.asarray(uv, float), b):
        return False
    return float(b @ (X / np.linalg.norm(X))) > math.cos(1e-7)


def project_markers(world: World, observer: str, t: float = 0.0, *,
                    check_occlusion: bool = False) -> dict[str, tuple[float, float]]:
    """Exact pixels of every other robot's marker centre seen by camera ``observer`` at ``t``.

    ``observer``: ``ROBOT`` or ``ROBOT/CAMERA`` (see :func:`render`); pixels
    are that camera's raw pixels through its lens, with its mount pose.
    A marker is listed when its centre is imaged (a pinhole: in front of the
    camera; any lens: less than ``max_angle`` off its axis), inside the
    image, and truly imaged there (not a fold-over of a strong distortion).
    This is the observer's entry of a SPEC observations file.  With
    ``check_occlusion`` a marker is also dropped when something else hides
    its centre (or, for a tag, when the camera sees the back of the card).
    """
    t = _check_time(t)
    camera = world.camera(observer)
    own, _ = world.observer(observer)
    wide = _is_wide(camera)
    T_cw = world.camera_pose(observer, t).inverse()
    scene = None
    if check_occlusion:
        scene, _ = _compile(world, t, observer)
    out: dict[str, tuple[float, float]] = {}
    for rname, wr in world.robots.items():
        if rname == own:
            continue
        T_cr = T_cw @ wr.pose_at(t)
        for m in wr.robot.markers.values():
            X = T_cr.apply(m.position)
            if not (wide or X[2] > 0):
                continue
            uv = camera.project(X)
            if not camera.in_image(uv) or not _visible_through_lens(camera, X, uv):
                continue
            if scene is not None and _occluded(scene, world, observer, rname, m, t):
                continue
            out[m.name] = (float(uv[0]), float(uv[1]))
    return out


def true_observations(world: World, t: float = 0.0, *, check_occlusion: bool = True
                      ) -> dict[str, dict[str, tuple[float, float]]]:
    """Exact pixels of every marker every camera of every robot sees at ``t``, in the SPEC observations form:
    keyed by observer (``ROBOT`` for a robot given with one ``camera``, ``ROBOT/CAMERA`` otherwise), each
    :func:`project_markers` of that camera (unhidden ones only with ``check_occlusion``, the default).
    Cameras seeing nothing are left out.  The true poses between robot frames: :func:`relative_pose`."""
    t = _check_time(t)
    out: dict[str, dict[str, tuple[float, float]]] = {}
    for wr in world.robots.values():
        for cname in wr.robot.mounts:
            key = wr.robot.observer_key(cname)
            seen = project_markers(world, key, t, check_occlusion=check_occlusion)
            if seen:
                out[key] = seen
    return out


def _occluded(scene: _Scene, world: World, observer: str, rname: str, marker: Any, t: float) -> bool:
    T_wc = world.camera_pose(observer, t)
    c = world.pose(rname, t).apply(marker.position)
    d = c - T_wc.t
    dist = float(np.linalg.norm(d))
    d = d / dist
    rgb = np.empty((1, 3))
    key = np.empty(1, np.int64)
    tex, tinfo, _ = _atlas(world)
    _cast(d.reshape(1, 3), np.eye(3), T_wc.t, scene.pf, scene.pi, scene.gf, scene.gi, scene.room_box(T_wc.t), scene.codes_arr,
          tex, tinfo, _LUT, np.zeros(9), np.zeros(3), 1.0, rgb, np.empty((1, 3)), key)
    k = int(key[0]) // _KEY_STRIDE if key[0] >= 0 else -1
    if k < 0 or scene.owner[k] != (rname, marker.name):
        return True
    if scene.pi[k, 0] == _QUAD:  # a tag: the printed side must face the camera
        return float(d @ scene.pf[k, 9:12]) >= 0.0
    return False


def surface_distance(world: World, points: Any, t: float = 0.0) -> np.ndarray:
    """Distance (n,) from each world point (n, 3) to the nearest surface of
    ``world`` at time ``t``: room walls, robot bodies, markers.  The ground
    truth for reconstructed point clouds (exact, no sampling)."""
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    scene, _ = _compile(world, _check_time(t))
    best = np.full(len(P), np.inf)
    for k in range(len(scene.rows)):
        f, kind = scene.pf[k], int(scene.pi[k, 0])
        d = P - f[:3]
        if kind == _SPHERE:
            dist = np.abs(np.linalg.norm(d, axis=1) - f[3])
        elif kind == _QUAD:
            a = np.clip(d @ f[3:6], -f[12], f[12])
            b = np.clip(d @ f[6:9], -f[13], f[13])
            dist = np.linalg.norm(d - a[:, None] * f[3:6] - b[:, None] * f[6:9], axis=1)
        elif kind == _BOX:
            local = d @ f[3:12].reshape(3, 3)  # coordinates along the box axes
            q = np.abs(local) - f[12:15]
            outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
            dist = np.where(outside > 0, outside, -np.max(q, axis=1))
        else:  # capped cylinder
            h = d @ f[3:6]
            rad = np.linalg.norm(d - h[:, None] * f[3:6], axis=1)
            q = np.stack([rad - f[6], np.abs(h) - f[7]], axis=1)
            outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
            dist = np.where(outside > 0, outside, -np.max(q, axis=1))
        best = np.minimum(best, dist)
    return best


# ---------------------------------------------------------------------------
# standard worlds
# ---------------------------------------------------------------------------

CAMERA_HEIGHT = 0.5  # m above the floor, of the target robot q in the standard worlds


def room_around(points: list[np.ndarray], seed: int, margin: float = 2.5, floor_decals: float = 0.0) -> Room:
    """A room containing ``points`` (world xy) with ``margin`` metres to spare, off-centre by the seed;
    ``floor_decals`` printed mats per square metre on its floor (:class:`~mutloc.sim.world.Room`)."""
    P = np.array(points)[:, :2]
    lo, hi = P.min(axis=0), P.max(axis=0)
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 104729])
    # Sizes in whole 2 m steps, so rooms around similar layouts share textures.
    size = np.maximum(2.0 * np.ceil((hi - lo + 2 * margin) / 2.0), [6.0, 6.0])
    # Shift the room off-centre but keep at least 1 m between the points and the walls.
    free = np.maximum(0.5 * (size - (hi - lo)) - 1.0, 0.0)
    centre = 0.5 * (lo + hi) + 0.5 * free * rng.uniform(-1.0, 1.0, 2)
    return Room(center=(float(centre[0]), float(centre[1])), size=(float(size[0]), float(size[1])),
                seed=int(seed), floor_decals=float(floor_decals))


def _pair(rig: Rig, source: str | None, target: str | None) -> tuple[str, str]:
    return rig.default_pair(source, target)


def two_robot_world(rig: Rig, T_qp: Pose, *, room: bool = True, seed: int = 0, source: str | None = None,
                    target: str | None = None, body: bool = True) -> World:
    """A standard room with robot q (``target``) and p (``source``, placed by ``T_qp``).

    q's camera is upright at :data:`CAMERA_HEIGHT` above the floor near the
    world origin, looking along world +x; p's camera pose is
    ``T_wq @ T_qp``.  Other robots of the rig are left out.  Without a room
    the background is black.  ``seed`` varies the room's textures and layout.
    """
    p, q = _pair(rig, source, target)
    if not isinstance(T_qp, Pose):
        raise InputError(f"T_qp must be a Pose, got {type(T_qp).__name__}")
    T_wq = camera_to_world_facing((0.0, 0.0, CAMERA_HEIGHT))
    T_wp = T_wq @ T_qp
    robots = {q: WorldRobot(rig.robot(q), T_wq, body=body), p: WorldRobot(rig.robot(p), T_wp, body=body)}
    rm = room_around([T_wq.t, T_wp.t], seed) if room else None
    return World(robots=robots, room=rm)


def default_path(distance: float = 2.0, period: float = 8.0, lateral: float = 0.3,
                 phases: tuple[float, float, float] = (0.0, 0.3, 1.0)) -> Callable[[float], Pose]:
    """T_qp(t) of p driving a smooth figure in front of q while facing it.

    p sways sideways by ``lateral * distance``, moves in and out by 15 %, and
    its heading wobbles 5 degrees around the direction to q; periodic in
    ``period``.  ``phases`` (radians) shift the sway, the in-and-out and the
    wobble.
    """
    w = 2 * math.pi / period
    ph_x, ph_z, ph_h = (float(a) for a in phases)

    def T_qp(t: float) -> Pose:
        x = lateral * distance * math.sin(w * t + ph_x)
        z = distance * (1.0 + 0.15 * math.sin(2 * w * t + ph_z))
        pos = np.array([x, 0.0, z])
        look = -pos / np.linalg.norm(pos)
        look = so3_exp([0.0, math.radians(5.0) * math.sin(1.5 * w * t + ph_h), 0.0]) @ look
        return looking_pose(pos, look)

    return T_qp


def moving_world(rig: Rig, T_qp: Callable[[float], Pose] | None = None, *, distance: float = 2.0,
                 period: float = 8.0, lateral: float = 0.3, pan_deg: float = 6.0, room: bool = True,
                 seed: int = 0, source: str | None = None, target: str | None = None, body: bool = True,
                 pan_phase: float = 1.0) -> World:
    """A standard room where p (``source``) moves relative to q (``target``) over time.

    ``T_qp(t)`` gives p's pose in q's frame (default :func:`default_path`);
    q stands at :data:`CAMERA_HEIGHT` near the origin and pans its heading by
    ``pan_deg`` degrees (sinusoidally, period ``period``, phase ``pan_phase``
    radians) so the background moves too.  Use with :func:`render` /
    :func:`relative_pose` at any ``t``.
    """
    p, q = _pair(rig, source, target)
    if not (math.isfinite(distance) and distance > 0 and math.isfinite(period) and period > 0):
        raise InputError(f"distance and period must be > 0, got {distance!r}, {period!r}")
    path = T_qp if T_qp is not None else default_path(distance, period, lateral)
    if not callable(path):
        raise InputError("T_qp must be a function of time returning a Pose")
    w = 2 * math.pi / period

    def T_wq(t: float) -> Pose:
        yaw = math.radians(pan_deg) * math.sin(w * t + pan_phase)
        return camera_to_world_facing((0.0, 0.0, CAMERA_HEIGHT), yaw=yaw)

    def T_wp(t: float) -> Pose:
        return T_wq(t) @ path(t)

    robots = {q: WorldRobot(rig.robot(q), T_wq, body=body), p: WorldRobot(rig.robot(p), T_wp, body=body)}
    rm = None
    if room:
        # Sample the path so the room holds all of it.
        pts = [T_wq(0.0).t] + [T_wp(s).t for s in np.linspace(0.0, period, 33)]
        rm = room_around(pts, seed)
    return World(robots=robots, room=rm)


def ball_visibility(world: World, observer: str, marker: str, t: float = 0.0, *, samples: int = 24) -> float:
    """Share (0..1) of a ball's image that ``observer`` sees unhidden at time ``t``: the ground truth
    of a detector's visible fraction.

    Rays on a ``samples`` x ``samples`` grid over the ball's disc (uniform in
    the image plane around its centre) are traced through the scene; the
    share whose first hit is the ball itself is returned.  0 when the ball
    is behind the camera.
    """
    t = _check_time(t)
    owner = next((rn for rn, wr in world.robots.items() if marker in wr.robot.markers), None)
    if owner is None:
        raise ObservationError(f"unknown marker {marker!r}")
    T_wc = world.camera_pose(observer, t)
    c = world.pose(owner, t).apply(world.robot(owner).robot.markers[marker].position)
    d = c - T_wc.t
    dist = float(np.linalg.norm(d))
    r = ball_radius(world.robot(owner).robot.markers[marker])
    if dist <= r:
        return 0.0
    u = d / dist
    a = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(u, a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    tan_a = r / math.sqrt(dist * dist - r * r)
    g = (np.arange(samples) + 0.5) / samples * 2.0 - 1.0
    gx, gy = np.meshgrid(g, g)
    inside = gx**2 + gy**2 < 0.999
    dirs = u + tan_a * (gx[inside, None] * e1 + gy[inside, None] * e2)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    scene, (tex, tinfo, _ids) = _compile(world, t)
    n = len(dirs)
    key = np.empty(n, np.int64)
    _cast(np.ascontiguousarray(dirs), np.eye(3), T_wc.t, scene.pf, scene.pi, scene.gf, scene.gi,
          scene.room_box(T_wc.t), scene.codes_arr, tex, tinfo, _LUT, np.zeros(9), np.zeros(3), 1.0,
          np.empty((n, 3)), np.empty((n, 3)), key)
    k = np.where(key >= 0, key // _KEY_STRIDE, -1)
    hit = np.array([kk >= 0 and scene.owner[kk] == (owner, marker) for kk in k])
    return float(hit.mean())


def scene_primitives(world: World, t: float = 0.0) -> list[dict[str, Any]]:
    """Every object this renderer draws of ``world`` at time ``t``, as plain data (world frame,
    metres; colours linear RGB in 0..1): what another renderer needs to draw the same scene
    (:mod:`mutloc.sim.blender`).

    Each item has ``kind`` (``"sphere"``, ``"quad"``, ``"box"``, ``"cylinder"``), ``robot`` and
    ``marker`` (the owner; ``""`` and None for the room, ``"#prop"`` for a prop), and its
    geometry: a sphere ``centre, radius, color, emission, specular, shininess``; a quad
    ``centre, u, v, half_u, half_v, color`` and ``surface`` (the room surface whose texture
    :func:`~mutloc.sim.world.room_textures` gives) or ``tag``; a box ``centre, R`` (columns: its
    axes) ``, half, color``; a capped cylinder ``centre, axis, radius, half_length, bands``
    (one linear RGB colour per band, top first) and ``cap``.
    """
    scene, (_tex, _tinfo, ids) = _compile(world, _check_time(t))
    tex_name = {v: k for k, v in ids.items()}
    rgb = lambda bgr: [float(bgr[2]), float(bgr[1]), float(bgr[0])]  # noqa: E731
    out: list[dict[str, Any]] = []
    for k, (f, (typ, i1, i2)) in enumerate(zip(scene.pf, scene.pi)):
        robot, marker = scene.owner[k]
        d: dict[str, Any] = {"robot": robot, "marker": marker, "centre": [float(x) for x in f[:3]]}
        if typ == _SPHERE:
            d.update(kind="sphere", radius=float(f[3]), color=rgb(f[4:7]), emission=rgb(f[7:10]),
                     specular=float(f[10]), shininess=float(f[11]))
        elif typ == _QUAD:
            d.update(kind="quad", u=f[3:6].tolist(), v=f[6:9].tolist(), half_u=float(f[12]), half_v=float(f[13]),
                     color=rgb(f[14:17]))
            name = tex_name.get(int(i1))
            if name is not None and name[0] == "room":
                d["surface"] = name[1]
            elif name is not None:
                d["tag"] = list(name[1:])
        elif typ == _BOX:
            d.update(kind="box", R=f[3:12].reshape(3, 3).tolist(), half=f[12:15].tolist(), color=rgb(f[15:18]))
        else:
            bits = scene.codes_arr[int(i1): int(i1) + int(i2)]
            d.update(kind="cylinder", axis=f[3:6].tolist(), radius=float(f[6]), half_length=float(f[7]),
                     bands=[rgb(f[8:11]) if b else rgb(f[11:14]) for b in bits], cap=rgb(f[14:17]))
        out.append(d)
    return out
