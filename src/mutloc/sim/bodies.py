"""Random robots with several cameras (any lens) and their exact observations.

For solver studies without images: each robot is a body (``base_link``: x
forward, y left, z up) carrying 2-3 cameras -- fisheye (180-200 degrees,
Kannala-Brandt coefficients), omnidirectional (Mei) or pinhole -- looking out
in different directions, and markers on its body.  :func:`body_observations`
projects every marker into every camera of the other robots through its
lens (the truth the solvers are judged on); :func:`pixel_information` is the
Fisher information of the relative pose from those pixels, computed by
differentiating the lens projections numerically (independent of the
solvers' ray weighting), for the Cramér-Rao bound.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from ..core.camera import Camera
from ..core.geometry import so3_exp
from ..core.lenses import FisheyeCamera, OmniCamera
from ..core.pose import Pose
from ..core.rig import Marker, Mount, Rig, Robot

__all__ = ["OPTICAL_IN_BASE", "random_lens", "random_body", "random_pair", "random_team", "back_to_back_fisheye",
           "body_observations", "pixel_information", "team_pixel_information"]

#: R_base_optical of a camera looking along the body's x axis (REP 103: optical z forward, x right, y down).
OPTICAL_IN_BASE = np.column_stack([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def _yaw(a: float) -> np.ndarray:
    return so3_exp(np.array([0.0, 0.0, a]))


def random_lens(rng: np.random.Generator, model: str) -> Any:
    """A realistic lens of ``model`` (``fisheye`` 180-200 degrees, ``omni``, ``pinhole`` 60-90 degrees)."""
    if model == "fisheye":
        w, h = 1280, 800
        fov = np.radians(rng.uniform(180.0, 200.0))
        k = np.array([rng.uniform(-0.02, 0.03), rng.uniform(-0.01, 0.005), rng.uniform(-0.002, 0.002),
                      rng.uniform(-0.0005, 0.0005)])
        theta = fov / 2
        theta_d = theta * (1 + k[0] * theta**2 + k[1] * theta**4 + k[2] * theta**6 + k[3] * theta**8)
        f = 0.5 * h / theta_d * 1.02  # the image circle just inside the short side
        K = [[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]]
        return FisheyeCamera(K, k, (w, h))
    if model == "omni":
        w, h = 1024, 768
        xi = rng.uniform(0.8, 1.2)
        f = rng.uniform(280.0, 340.0)
        K = [[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]]
        return OmniCamera(K, [rng.uniform(-0.05, 0.05), rng.uniform(-0.01, 0.01), 0.0005, -0.0005], xi, (w, h))
    w, h = 960, 540
    fov = np.radians(rng.uniform(60.0, 90.0))
    f = 0.5 * w / np.tan(fov / 2)
    K = [[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]]
    return Camera(K, [rng.uniform(-0.1, 0.1), rng.uniform(-0.05, 0.05), 0.0, 0.0, 0.0], (w, h))


def random_body(rng: np.random.Generator, name: str, n_markers: int = 4,
                models: tuple[str, ...] = ("fisheye", "omni", "pinhole")) -> Robot:
    """A body robot with 2-3 cameras of the given lens models looking out around it and ``n_markers`` markers
    on its body (a 0.4 m box up to 0.6 m high)."""
    n_cam = int(rng.integers(2, 4))
    yaws = np.sort(rng.uniform(0, 2 * np.pi, n_cam)) if n_cam == 3 else np.array([0.0, np.pi])
    yaws = yaws + rng.uniform(-0.2, 0.2, n_cam)
    cams = {}
    names = ("front", "back", "side")
    for i in range(n_cam):
        lens = random_lens(rng, str(rng.choice(models)))
        R = _yaw(yaws[i]) @ so3_exp(np.array([0.0, rng.uniform(-0.15, 0.15), 0.0])) @ OPTICAL_IN_BASE
        t = _yaw(yaws[i]) @ np.array([0.2, 0.0, 0.0]) + np.array([0.0, 0.0, rng.uniform(0.25, 0.45)])
        cams[names[i]] = Mount(names[i], lens, Pose(R, t))
    markers = {}
    for j in range(n_markers):
        pos = np.array([rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), rng.uniform(0.1, 0.6)])
        markers[f"{name}{j}"] = Marker(f"{name}{j}", name, pos)
    return Robot(name, None, markers, cameras=cams)


def random_pair(rng: np.random.Generator, dmin: float = 1.5, dmax: float = 5.0) -> tuple[Rig, dict[str, Pose], Pose]:
    """Robots ``p`` and ``q`` (:func:`random_body`) ``dmin``-``dmax`` m apart at any headings (often turned
    away from each other), nearly upright: ``(rig, world poses, T_qp)``."""
    rig = Rig({"p": random_body(rng, "p"), "q": random_body(rng, "q")})
    d, a = rng.uniform(dmin, dmax), rng.uniform(0, 2 * np.pi)
    poses = {"q": Pose(so3_exp(np.array([0.0, 0.0, rng.uniform(0, 2 * np.pi)])), np.zeros(3)),
             "p": Pose(so3_exp(np.array([rng.normal(0, 0.05), rng.normal(0, 0.05), rng.uniform(0, 2 * np.pi)])),
                       np.array([d * np.cos(a), d * np.sin(a), rng.normal(0, 0.05)]))}
    return rig, poses, poses["q"].inverse() @ poses["p"]


def random_team(rng: np.random.Generator, n: int, *, pinhole: bool = False, rmin: float = 1.2,
                rmax: float = 2.5, dmin: float = 1.5) -> tuple[Rig, dict[str, Pose]]:
    """``n`` robots ``r0``... on a circle of radius ``rmin``-``rmax`` m around the team (at least ``dmin`` m
    apart): ``(rig, world poses)``, each pose that of the robot's frame.

    Bodies (:func:`random_body`) at any headings (so some pairs turned away from each other, seen by back
    cameras only); with ``pinhole``, the peer: robots with one forward pinhole camera each (60-90 degrees,
    their frame the camera's optical frame, the same 0.4 m box of four markers), facing the centre of the
    circle within +-15 degrees."""
    while True:
        radius = rng.uniform(rmin, rmax)
        angles = rng.uniform(0, 2 * np.pi, n)
        xy = radius * np.column_stack([np.cos(angles), np.sin(angles)])
        if min(np.linalg.norm(xy[i] - xy[j]) for i in range(n) for j in range(i)) >= dmin:
            break
    robots, poses = {}, {}
    for i in range(n):
        name = f"r{i}"
        yaw = angles[i] + np.pi + np.radians(rng.uniform(-15, 15)) if pinhole else rng.uniform(0, 2 * np.pi)
        base = Pose(so3_exp(np.array([rng.normal(0, 0.05), rng.normal(0, 0.05), yaw])),
                    np.array([xy[i, 0], xy[i, 1], rng.normal(0, 0.05)]))
        if not pinhole:
            robots[name], poses[name] = random_body(rng, name), base
            continue
        mount = Pose(so3_exp(np.array([0.0, rng.uniform(-0.15, 0.15), 0.0])) @ OPTICAL_IN_BASE,
                     np.array([0.2, 0.0, rng.uniform(0.25, 0.45)]))
        to_cam = mount.inverse()
        markers = {f"{name}{j}": Marker(f"{name}{j}", name, to_cam.apply(
            np.array([rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), rng.uniform(0.1, 0.6)]))) for j in range(4)}
        robots[name] = Robot(name, random_lens(rng, "pinhole"), markers)
        poses[name] = base @ mount
    return Rig(robots), poses


def back_to_back_fisheye(name: str, markers: Mapping[str, Any], *, fov_deg: float = 195.0) -> Robot:
    """A body with two fisheyes (front and back, 0.3 m up) and the given markers ``{name: position}``."""
    theta = np.radians(fov_deg) / 2
    k = np.array([0.012, -0.004, 0.0006, -0.0001])
    theta_d = theta * (1 + k[0] * theta**2 + k[1] * theta**4 + k[2] * theta**6 + k[3] * theta**8)
    f = 400 / theta_d
    K = [[f, 0, 639.5], [0, f, 399.5], [0, 0, 1]]
    cams = {c: Mount(c, FisheyeCamera(K, k, (1280, 800)), Pose(_yaw(a) @ OPTICAL_IN_BASE,
                                                                 _yaw(a) @ np.array([0.15, 0.0, 0.0]) + [0, 0, 0.3]))
            for c, a in (("front", 0.0), ("back", np.pi))}
    return Robot(name, None, {m: Marker(m, name, np.asarray(p, float)) for m, p in markers.items()}, cameras=cams)


def body_observations(rig: Rig, poses: Mapping[str, Pose], *, sigma: float = 0.0,
                      rng: np.random.Generator | None = None) -> dict[str, dict[str, list[float]]]:
    """Every marker every camera sees (in its image, within its lens's field), keyed ``ROBOT/CAMERA``, raw
    pixels plus Gaussian noise of ``sigma`` px; ``poses[name]`` is each robot's pose in a common world."""
    out: dict[str, dict[str, list[float]]] = {}
    for o, robot in rig.robots.items():
        for cname, mount in robot.mounts.items():
            T_cw = (poses[o] @ mount.pose).inverse()
            for other, orobot in rig.robots.items():
                if other == o:
                    continue
                for mname, m in orobot.markers.items():
                    X = T_cw.apply(poses[other].apply(m.position))
                    uv = np.asarray(mount.camera.project(X), float)
                    if not np.all(np.isfinite(uv)) or not mount.camera.in_image(uv):
                        continue
                    # where a lens's polynomial folds back (past its calibrated field) it images nothing
                    if not _round_trips(mount.camera, uv, X):
                        continue
                    if sigma > 0:
                        uv = uv + sigma * rng.standard_normal(2)
                    out.setdefault(robot.observer_key(cname), {})[mname] = uv.tolist()
    return out


def _round_trips(camera: Any, uv: np.ndarray, X: np.ndarray) -> bool:
    try:
        b = np.asarray(camera.pixels_to_bearings(uv), float)
    except Exception:  # noqa: BLE001 -- a pinhole Camera raises where it cannot undistort
        return False
    return bool(np.all(np.isfinite(b)) and b @ X / np.linalg.norm(X) > np.cos(1e-6))


def pixel_information(rig: Rig, observations: Mapping[str, Mapping[str, Any]], source: str, target: str,
                      T_qp: Pose, eps: float = 1e-6) -> np.ndarray:
    """Fisher information (6x6, per unit pixel variance) of ``T_qp`` from the pixels of ``observations``
    between the pair, in the SPEC's perturbation (left rotation vector, translation): central differences
    of each lens's projection."""
    rows = []
    for key, seen in observations.items():
        rname, cname = rig.observer(key)
        if rname not in (source, target):
            continue
        mount = rig.robots[rname].mounts[cname]
        for mname in seen:
            if rig.owner(mname) not in (source, target):
                continue
            P = rig.marker(mname).position

            def pix(d: np.ndarray) -> np.ndarray:
                T = Pose(so3_exp(d[:3]) @ T_qp.R, T_qp.t + d[3:])
                X = T.inverse().apply(P) if rname == source else T.apply(P)
                return np.asarray(mount.camera.project(mount.pose.inverse().apply(X)), float)

            J = np.empty((2, 6))
            for k in range(6):
                d = np.zeros(6)
                d[k] = eps
                J[:, k] = (pix(d) - pix(-d)) / (2 * eps)
            rows.append(J)
    J = np.vstack(rows)
    return J.T @ J


def team_pixel_information(rig: Rig, observations: Mapping[str, Mapping[str, Any]], reference: str,
                           poses: Mapping[str, Pose], robots: list[str], eps: float = 1e-6) -> np.ndarray:
    """Joint Fisher information (6k x 6k over ``robots``, per unit pixel variance) of the poses
    ``T_reference_robot`` from the pixels of ``observations`` among ``robots`` and the reference (the
    others ignored); ``poses[name]`` is each robot's pose in ``reference``'s frame.  Central differences of
    each lens's projection in the SPEC's perturbation (left rotation vector, translation), as
    :func:`pixel_information`."""
    index = {r: i for i, r in enumerate(robots)}
    rows = []
    for key, seen in observations.items():
        rname, cname = rig.observer(key)
        if rname != reference and rname not in index:
            continue
        mount = rig.robots[rname].mounts[cname]
        for mname in seen:
            owner = rig.owner(mname)
            if owner != reference and owner not in index:
                continue
            P = rig.marker(mname).position

            def pix(who: str, d: np.ndarray) -> np.ndarray:
                Ts = {n: poses[n] for n in (rname, owner)}
                if who != reference:
                    T = poses[who]
                    Ts[who] = Pose(so3_exp(d[:3]) @ T.R, T.t + d[3:])
                X = Ts[rname].inverse().apply(Ts[owner].apply(P))
                return np.asarray(mount.camera.project(mount.pose.inverse().apply(X)), float)

            J = np.zeros((2, 6 * len(robots)))
            for who in (rname, owner):
                if who == reference:
                    continue
                for k in range(6):
                    d = np.zeros(6)
                    d[k] = eps
                    J[:, 6 * index[who] + k] = (pix(who, d) - pix(who, -d)) / (2 * eps)
            rows.append(J)
    J = np.vstack(rows) if rows else np.zeros((0, 6 * len(robots)))
    return J.T @ J
