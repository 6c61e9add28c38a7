"""Synthetic observation sequences for tracking: a known smooth trajectory
of ``T_qp``, every marker projected through the rig's cameras, then the
troubles a tracker must survive -- pixel noise, markers missing, stretches
where one camera sees nothing, detections far off.  No rendering; the
tests, the filter benchmark and the README's figures use it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable, Sequence

import numpy as np

from ..core.observations import ObservationSet
from ..core.pose import Pose
from ..core.rig import Rig

if TYPE_CHECKING:
    from .world import World

__all__ = ["ObservationSequence", "observation_sequence", "CameraRecords", "camera_records", "correct_detections", "LightIdentity",
           "light_identity", "light_view", "panning_lights", "varied_world"]


@dataclass
class ObservationSequence:
    """``frames[i]`` (stamped ``times[i]``) observed at true pose ``truth[i]``;
    ``outlier[i]``: frame i holds a detection moved far off (``outlier_marker[i]`` names it);
    ``blind[i]``: the robots that see none of the other's markers in frame i ('p', 'p+q'; '' if none)."""

    times: np.ndarray
    frames: list[ObservationSet]
    truth: Pose
    outlier: np.ndarray
    blind: list[str]
    outlier_marker: list[str] = field(default_factory=list)


def observation_sequence(rig: Rig, path: Callable[[float], Pose] | None = None, *, duration: float = 10.0,
                         fps: float = 30.0, pixel_sigma: float = 2.0, drop: float = 0.2,
                         blind: Sequence[tuple[float, float, str]] = ((2.0, 3.0, "p"), (6.0, 7.0, "q")),
                         outliers: float = 0.02, outlier_px: tuple[float, float] = (30.0, 60.0), seed: int = 0,
                         source: str | None = None, target: str | None = None) -> ObservationSequence:
    """Observations of ``source`` (p) and ``target`` (q) along ``path``
    (``T_qp(t)``; default :func:`mutloc.sim.render.default_path` at 2 m).

    Each frame: every marker in front of the camera and inside its image is
    seen with Gaussian noise ``pixel_sigma``; with probability ``drop`` one
    marker (at random) is missing; during each ``blind`` stretch ``(start,
    end, robot)`` that robot sees nothing; with probability ``outliers`` one
    remaining detection is moved ``outlier_px`` pixels (uniform) in a random
    direction.
    """
    from .render import default_path

    source, target = rig.default_pair(source, target)
    path = path if path is not None else default_path(2.0, 8.0, 0.3)
    rng = np.random.default_rng(seed)
    n = int(round(duration * fps))
    times = np.arange(n) / fps
    poses = [path(float(t)) for t in times]
    frames: list[ObservationSet] = []
    is_out = np.zeros(n, bool)
    blind_of: list[str] = []
    out_marker: list[str] = []
    robots = {r: rig.robot(r) for r in (source, target)}
    for i, (t, T) in enumerate(zip(times, poses)):
        observer, marker, uv = [], [], []
        for obs_name, other, to_obs in ((source, target, T.inverse()), (target, source, T)):
            cam = robots[obs_name].camera
            names = list(robots[other].markers)
            X = to_obs.apply(robots[other].marker_positions(names))
            px = cam.project(X)
            for name, x, p in zip(names, X, px):
                if x[2] <= 0 or not np.all(np.isfinite(p)) or (cam.size is not None and not cam.in_image(p)):
                    continue
                observer.append(obs_name)
                marker.append(name)
                uv.append(p + rng.normal(scale=pixel_sigma, size=2))
        who = {r for a, b, r in blind if a <= t < b}
        blind_of.append("+".join(sorted(who)))
        keep = [k for k, o in enumerate(observer) if o not in who]
        if keep and rng.random() < drop:
            keep.pop(int(rng.integers(len(keep))))
        out_marker.append("")
        if keep and rng.random() < outliers:
            k = keep[int(rng.integers(len(keep)))]
            ang = rng.uniform(0, 2 * np.pi)
            uv[k] = uv[k] + rng.uniform(*outlier_px) * np.array([np.cos(ang), np.sin(ang)])
            is_out[i] = True
            out_marker[-1] = marker[k]
        frames.append(ObservationSet([observer[k] for k in keep], [marker[k] for k in keep],
                                     np.array([uv[k] for k in keep]).reshape(-1, 2), float(t)))
    return ObservationSequence(times, frames, Pose.concatenate(poses), is_out, blind_of, out_marker)


def correct_detections(world: "World", t: float, rng: np.random.Generator | None = None,
                       sigma: float = 0.05) -> ObservationSet:
    """What a perfect detector reports in a rendered world at ``t``: each
    robot's view of the other robots' marker centres that are in its image
    and not hidden -- blinking lights only while they are on (a light that is
    off shows nothing) -- at their exact pixels plus ``sigma`` px of noise,
    stamped ``t``.  What "a correct detection would solve" is measured with."""
    from .render import project_markers
    from .world import light_is_on

    rng = rng if rng is not None else np.random.default_rng(0)
    markers = {m.name: m for wr in world.robots.values() for m in wr.robot.markers.values()}
    observer: list[str] = []
    name: list[str] = []
    uv: list[np.ndarray] = []
    for r in world.robots:
        for m, p in project_markers(world, r, t, check_occlusion=True).items():
            if markers[m].blink_hz is not None and not light_is_on(markers[m], t):
                continue
            observer.append(r)
            name.append(m)
            uv.append(np.asarray(p, float) + rng.normal(0.0, sigma, 2))
    return ObservationSet(observer, name, np.reshape(uv, (-1, 2)), float(t))


def light_view(world: "World", observer: str, lights: Sequence[str], n: int, fps: float,
               seed: int) -> tuple[list[np.ndarray], list[dict], list[dict]]:
    """Robot ``observer``'s first ``n`` rendered frames (frame ``k`` rendered
    with seed ``seed + k``, sensor noise 1 grey level), and per frame the true
    pixels of the ``lights`` in view and not hidden, and which are on: the
    input of :func:`light_identity`."""
    from .render import project_markers, render
    from .world import light_is_on

    markers = {m.name: m for wr in world.robots.values() for m in wr.robot.markers.values()}
    frames, truth, lit = [], [], []
    for k in range(n):
        t = k / fps
        frames.append(render(world, observer, t, seed=seed + k, noise_sigma=1.0))
        truth.append({m: u for m, u in project_markers(world, observer, t, check_occlusion=True).items()
                      if m in lights})
        lit.append({m: light_is_on(markers[m], t) for m in lights})
    return frames, truth, lit


def varied_world(rig: Rig, seed: int, *, distance: float = 2.0, period: float = 8.0, pan_deg: float = 6.0,
                 vary: bool = True) -> tuple[Rig, "World"]:
    """:func:`mutloc.sim.render.moving_world` in room ``seed`` where, with
    ``vary``, the seed also draws the motion and the blinks: the phases of
    p's sway, in-and-out and heading wobble and of q's pan (uniform), the
    sway (0.2-0.4 of ``distance``), the path period and pan amplitude (x 0.8-1.2)
    and each blinking light's phase (uniform in cycles).  Without ``vary``
    only the room changes with the seed.  Returns the rig (lights with their
    drawn phases; a tracker does not read them) and the world."""
    from dataclasses import replace

    from .render import default_path, moving_world

    if not vary:
        return rig, moving_world(rig, distance=distance, seed=seed, period=period, pan_deg=pan_deg)
    rng = np.random.default_rng([seed, 0x5CE4])
    phases = tuple(rng.uniform(0.0, 2 * np.pi, 3))
    lateral = float(rng.uniform(0.2, 0.4))
    period = period * float(rng.uniform(0.8, 1.2))
    pan_deg = pan_deg * float(rng.uniform(0.8, 1.2))
    pan_phase = float(rng.uniform(0.0, 2 * np.pi))
    robots = {}
    for rname in rig.robots:
        r = rig.robot(rname)
        ms = {m: (replace(mk, extra={**mk.extra, "phase": float(rng.uniform())}) if mk.blink_hz is not None else mk)
              for m, mk in r.markers.items()}
        robots[rname] = replace(r, markers=ms)
    rig = Rig(robots)
    path = default_path(distance, period, lateral, phases)
    return rig, moving_world(rig, path, distance=distance, seed=seed, period=period, pan_deg=pan_deg,
                             pan_phase=pan_phase)


def panning_lights(distance: float, seed: int, n: int, fps: float = 30.0, *, size: tuple[int, int] = (960, 540),
                   f: float = 800.0, period: float = 4.0, pan_deg: float = 15.0, vary: bool = False) -> tuple:
    """Robot q's view of p's blinking lights while p drives a ``period`` s
    path ``distance`` m away and q's camera pans by +-``pan_deg``
    (bench/blink_identity.py's sequences): the rig, p's markers, and
    :func:`light_view`'s frames, truth and lit states (noise seed ``1000 seed + k``).
    ``vary``: the seed draws the motion and blink phases too (:func:`varied_world`)."""
    from .world import standard_rig

    rig, world = varied_world(standard_rig("lights", size=size, f=f), seed, distance=distance, period=period,
                              pan_deg=pan_deg, vary=vary)
    markers = rig.robot("p").markers
    return (rig, markers, *light_view(world, "q", list(markers), n, fps, seed * 1000))


@dataclass
class LightIdentity:
    """How well a blink tracker named the lights of a rendered sequence.

    ``good`` of ``total``: (frame, light) pairs after the first second with
    the light lit and visible, reported under its own name within the
    tolerance of its true projection and nearer it than any other light;
    ``wrong``: reports (any frame) nearer another light than their own, or
    measured lit more than 10 px from their own; ``failures``: (frame,
    light, why) for each counted pair that was not good."""

    good: int
    total: int
    wrong: int
    failures: list[tuple[int, str, str]]

    @property
    def fraction(self) -> float:
        return self.good / max(self.total, 1)


def light_identity(results: Sequence, truth: Sequence[dict], lit: Sequence[dict], fps: float,
                   tol: float = 3.0) -> LightIdentity:
    """Score blink-tracker ``results`` (one DetectionResult per frame) against
    each frame's true light pixels ``truth`` ({name: uv}) and ``lit``
    ({name: bool}); frames within the first second are not counted (a blink
    needs a history to be named), wrong labels are counted in every frame."""
    good = total = wrong = 0
    failures: list[tuple[int, str, str]] = []
    for k, (res, tr, on) in enumerate(zip(results, truth, lit)):
        for name, det in res.detections.items():
            d = {o: float(np.hypot(*(det.uv - np.asarray(u)))) for o, u in tr.items()}
            if name in d and (min(d, key=d.get) != name or (not det.predicted and d[name] > 10.0)):
                wrong += 1
        if k < fps:
            continue
        for name in tr:
            if not on[name]:
                continue
            total += 1
            det = res.detections.get(name)
            if det is None:
                failures.append((k, name, "missing"))
                continue
            d = {o: float(np.hypot(*(det.uv - np.asarray(u)))) for o, u in tr.items()}
            if d[name] <= tol and min(d, key=d.get) == name:
                good += 1
            else:
                failures.append((k, name, f"off by {d[name]:.1f} px"))
    return LightIdentity(good, total, wrong, failures)


@dataclass
class CameraRecords:
    """Observation-log records of free-running cameras: ``frames[i]``
    holds what the cameras capturing at ``times[i]`` saw (one camera's
    observations, or several where their frames coincide), ``truth[i]`` the
    true ``T_qp`` (or, with ``poses``, every robot's pose) at that time."""

    times: np.ndarray
    frames: list[ObservationSet]
    truth: Pose
    cameras: list[tuple[str, ...]]


def camera_records(rig: Rig, path: Callable[[float], Pose] | None = None, *, duration: float = 4.0,
                   rates: dict[str, float] | None = None, offsets: dict[str, float] | None = None,
                   pixel_sigma: float = 1.0, seed: int = 0, source: str | None = None,
                   target: str | None = None) -> CameraRecords:
    """Records of two cameras, each capturing at its own ``rates[robot]``
    (frames/s, default 30) from ``offsets[robot]`` seconds (default 0) along
    ``path`` (``T_qp(t)``, default :func:`mutloc.sim.render.default_path`):
    every marker in front of the observing camera and inside its image,
    projected at the frame's own time with Gaussian noise ``pixel_sigma``.
    Frames of both cameras at the same instant make one record (a
    synchronized log); otherwise each record holds one camera's frame."""
    from .render import default_path

    source, target = rig.default_pair(source, target)
    path = path if path is not None else default_path(2.0, 8.0, 0.3)
    rates = {source: 30.0, target: 30.0, **(rates or {})}
    offsets = {source: 0.0, target: 0.0, **(offsets or {})}
    rng = np.random.default_rng(seed)
    stamps: dict[float, list[str]] = {}
    for r in (source, target):
        k = np.arange(int(np.floor((duration - offsets[r]) * rates[r] - 1e-9)) + 1)
        for t in np.round(offsets[r] + k / rates[r], 9):
            stamps.setdefault(float(t), []).append(r)
    times = np.array(sorted(stamps))
    robots = {r: rig.robot(r) for r in (source, target)}
    frames, truth, cams = [], [], []
    for t in times:
        T = path(float(t))
        observer, marker, uv = [], [], []
        for obs_name in sorted(stamps[float(t)], key=(source, target).index):
            other, to_obs = (target, T.inverse()) if obs_name == source else (source, T)
            cam = robots[obs_name].camera
            names = list(robots[other].markers)
            X = to_obs.apply(robots[other].marker_positions(names))
            for name, x, p in zip(names, X, cam.project(X)):
                if x[2] <= 0 or not np.all(np.isfinite(p)) or (cam.size is not None and not cam.in_image(p)):
                    continue
                observer.append(obs_name)
                marker.append(name)
                uv.append(p + rng.normal(scale=pixel_sigma, size=2))
        frames.append(ObservationSet(observer, marker, np.array(uv).reshape(-1, 2), float(t)))
        truth.append(T)
        cams.append(tuple(stamps[float(t)]))
    return CameraRecords(times, frames, Pose.concatenate(truth), cams)
