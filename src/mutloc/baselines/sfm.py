"""Structure from motion over many images: the Bundler baseline, with COLMAP.

The paper compares mutual localization with Bundler run over *all* the images
of its experiment.  :class:`SfmScene` does the same with a maintained engine,
COLMAP (through ``pycolmap``): SIFT features, matching of every image pair
(or of the pairs given) with geometric verification, incremental mapping
with bundle adjustment.  The
camera intrinsics are fixed to the calibration (``OPENCV`` or
``FULL_OPENCV`` model; focal length, principal point and distortion are never
refined), so only poses and structure are estimated.

Structure from motion recovers a scene only up to a similarity; the metric
scale comes from one known distance between two registered camera centres
(:class:`ScaleReference`): an oracle (exact) distance favours the baseline.

The same scene object triangulates points from poses given from outside
(:meth:`SfmScene.triangulate`, COLMAP's point triangulator on the same
features and verified matches), so different pose sources are compared with
one triangulator.

Everything runs in a temporary directory (removed on exit), on the CPU,
with fixed random seeds; nothing is downloaded.  Matching uses
``num_threads`` threads (each pair is computed alone, so the result does not
depend on them); feature extraction runs on one thread, because with several
COLMAP numbers the images in the order their features are finished, and the
mapper breaks ties by that number; incremental mapping and triangulation run
on one thread too (Ceres sums a large bundle adjustment's terms in a varying
order on several).  The same images and seed then give the same model.
"""

from __future__ import annotations

import shutil
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from contextlib import nullcontext
from typing import Any, Callable, ContextManager, Iterable, Mapping

import numpy as np

from .._extras import require
from ..core.camera import Camera
from ..core.pose import Pose
from ..errors import InputError, NoSolutionError

__all__ = ["SfmScene", "SfmResult", "ScaleReference", "MAX_FEATURES", "colmap_camera_params", "farthest_reference"]

# SIFT features per image: COLMAP's default is 8192.  The experiments'
# 960x540 renders give 1500-2000 each (measured), so the cap does not bind there.
MAX_FEATURES = 4096


@dataclass(frozen=True)
class ScaleReference:
    """A known distance (m) between the camera centres of images ``a`` and ``b``."""

    a: str
    b: str
    distance: float


def farthest_reference(centres: Mapping[str, Any], registered: Iterable[str]) -> ScaleReference:
    """The scale reference of the two registered images farthest apart among
    ``centres`` (name -> true camera centre), with their true distance;
    :class:`~mutloc.errors.NoSolutionError` when fewer than two are registered."""
    reg = set(registered)
    names = [n for n in centres if n in reg]
    if len(names) < 2:
        raise NoSolutionError("fewer than two reference images registered: no scale reference")
    dist = lambda ab: float(np.linalg.norm(np.asarray(centres[ab[0]], float) - np.asarray(centres[ab[1]], float)))
    a, b = max(((a, b) for i, a in enumerate(names) for b in names[i + 1:]), key=dist)
    return ScaleReference(a, b, dist((a, b)))


@dataclass
class SfmResult:
    """Registered images and their poses.

    ``poses[name]`` is the camera -> world pose ``T_wc`` of each registered
    image in the reconstruction's frame, scaled to metres when a scale
    reference was given (``scale`` is the factor applied, 1.0 otherwise).
    """

    poses: dict[str, Pose]
    images: int
    points: int
    scale: float = 1.0
    models: int = 1
    mean_reprojection_px: float = float("nan")
    unregistered: list[str] = field(default_factory=list)

    def scaled(self, reference: ScaleReference) -> "SfmResult":
        """The result scaled so that the reference images' camera centres are
        ``reference.distance`` apart (both must be registered, else
        :class:`~mutloc.errors.NoSolutionError`)."""
        if not (np.isfinite(reference.distance) and reference.distance > 0):
            raise InputError(f"scale distance must be a positive number, got {reference.distance!r}")
        for n in (reference.a, reference.b):
            if n not in self.poses:
                raise NoSolutionError(f"scale reference image {n!r} was not registered")
        d = float(np.linalg.norm(self.poses[reference.a].t - self.poses[reference.b].t))
        if not d > 0:
            raise NoSolutionError("the scale reference images share one camera centre")
        f = float(reference.distance) / d
        return replace(self, poses={n: Pose(T.R, T.t * f) for n, T in self.poses.items()}, scale=self.scale * f)

    def relative(self, source: str, target: str) -> Pose:
        """``T_target_source`` (``x_target = R x_source + t``) between two registered images."""
        for n in (source, target):
            if n not in self.poses:
                raise NoSolutionError(f"image {n!r} was not registered by structure from motion")
        return self.poses[target].inverse() @ self.poses[source]


def colmap_camera_params(camera: Camera) -> tuple[str, list[float]]:
    """COLMAP camera model name and parameters of a mutloc camera.

    COLMAP puts pixel (0, 0) at the top-left *corner* of the image, mutloc
    (like OpenCV) at the centre of the top-left pixel: the principal point
    moves by half a pixel.
    """
    K, d = camera.K, camera.dist
    if abs(K[0, 1]) > 1e-12:
        raise InputError("COLMAP's camera models have no skew; the camera's K[0, 1] must be 0")
    base = [K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5]
    if np.any(d[4:] != 0):
        return "FULL_OPENCV", [float(x) for x in base + list(d[:8])]
    return "OPENCV", [float(x) for x in base + list(d[:4])]


def _pose_from_rigid(cam_from_world: Any) -> Pose:
    """``T_wc`` of COLMAP's ``cam_from_world`` (a Rigid3d)."""
    M = np.asarray(cam_from_world.matrix(), dtype=float)
    return Pose(M[:, :3], M[:, 3]).inverse()


def _pycolmap() -> Any:
    return require("pycolmap", "structure from motion (COLMAP)", "experiments")


def _rigid_from_pose(T_wc: Pose) -> Any:
    pycolmap = _pycolmap()

    T_cw = T_wc.inverse()
    return pycolmap.Rigid3d(np.column_stack([T_cw.R, T_cw.t]))


class SfmScene:
    """A set of images with their calibrated cameras, features and verified matches.

    ``images`` maps a name to a BGR (or grey) uint8 image; ``cameras`` gives
    each image's camera (one :class:`~mutloc.core.camera.Camera` for all, or
    a mapping name -> camera).  Features are extracted and matched on
    entering the ``with`` block -- every pair of images, or only ``pairs``
    (name pairs, either order) when given; :meth:`reconstruct` and
    :meth:`triangulate` then work on them.  Use as a context manager: the
    working directory is deleted on exit.  ``timer(stage)``, if given, is
    entered around each stage (a context manager; for run-time reports).
    """

    def __init__(self, images: Mapping[str, np.ndarray], cameras: Camera | Mapping[str, Camera], *,
                 seed: int = 0, num_threads: int = 2, max_features: int = MAX_FEATURES,
                 pairs: Iterable[tuple[str, str]] | None = None, workdir: str | Path | None = None,
                 progress: bool = False, verbose: bool = False,
                 timer: Callable[[str], ContextManager[Any]] | None = None) -> None:
        _pycolmap()  # before any work
        if len(images) < 2:
            raise InputError(f"structure from motion needs at least two images, got {len(images)}")
        for n in images:
            if not n or "/" in n or "\\" in n or n.startswith("."):
                raise InputError(f"image name {n!r} must be a plain file name")
        cams = {n: cameras for n in images} if isinstance(cameras, Camera) else dict(cameras)
        missing = [n for n in images if n not in cams]
        if missing:
            raise InputError(f"no camera for images {missing[:5]}")
        for n, img in images.items():
            a = np.asarray(img)
            if a.dtype != np.uint8 or a.ndim not in (2, 3):
                raise InputError(f"image {n!r} must be a uint8 grey or BGR array")
            size = cams[n].size
            if size is not None and (a.shape[1], a.shape[0]) != tuple(size):
                raise InputError(f"image {n!r} is {a.shape[1]}x{a.shape[0]}, its camera {size[0]}x{size[1]}")
        self._images = images
        self._cameras = cams
        self.seed = int(seed)
        self.num_threads = max(1, int(num_threads))
        self.max_features = int(max_features)
        self._own_dir = workdir is None
        self._workdir = Path(workdir) if workdir is not None else None
        self.progress = bool(progress)
        self.verbose = bool(verbose)
        self.pairs: list[tuple[str, str]] | None = None
        if pairs is not None:
            seen = set()
            for a, b in pairs:
                if a not in images or b not in images or a == b:
                    raise InputError(f"image pair ({a!r}, {b!r}) is not two different images of the scene")
                seen.add((a, b) if a < b else (b, a))
            self.pairs = sorted(seen)
        self._timer = timer or (lambda _name: nullcontext())

    # -- lifecycle ---------------------------------------------------------

    def __enter__(self) -> "SfmScene":
        if self._workdir is None:
            self._workdir = Path(tempfile.mkdtemp(prefix="mutloc-sfm-"))
        self._workdir.mkdir(parents=True, exist_ok=True)
        try:
            self._prepare()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        """Delete the working directory (when it is a temporary one)."""
        if self._own_dir and self._workdir is not None:
            shutil.rmtree(self._workdir, ignore_errors=True)
            self._workdir = None

    @property
    def database(self) -> Path:
        return self._dir / "database.db"

    @property
    def image_dir(self) -> Path:
        return self._dir / "images"

    @property
    def _dir(self) -> Path:
        if self._workdir is None:
            raise InputError("SfmScene is closed (use it inside a with block)")
        return self._workdir

    # -- features and matches ---------------------------------------------

    def _prepare(self) -> None:
        import cv2
        pycolmap = _pycolmap()
        from tqdm import tqdm

        if not self.verbose:
            pycolmap.logging.minloglevel = 2  # errors only (glog levels: 0 info, 1 warning)
        bar = tqdm(total=2, desc="structure from motion: features, matches", unit="step",
                   disable=not self.progress, leave=False)
        pycolmap.set_random_seed(self.seed)
        self.image_dir.mkdir(exist_ok=True)
        groups: dict[tuple[str, tuple[float, ...], int, int], list[str]] = {}
        with self._timer("SfM: feature extraction"):
            for n, img in self._images.items():
                fname = n + ".png"
                if not cv2.imwrite(str(self.image_dir / fname), np.asarray(img)):
                    raise InputError(f"could not write image {n!r}")
                model, params = colmap_camera_params(self._cameras[n])
                h, w = np.asarray(img).shape[:2]
                groups.setdefault((model, tuple(params), w, h), []).append(fname)
            extraction = pycolmap.FeatureExtractionOptions()
            # One thread: COLMAP numbers the images in the order their features
            # are written, which with several threads varies run to run, and the
            # mapper breaks ties by that number (measured: a different model).
            extraction.num_threads = 1
            extraction.use_gpu = False
            extraction.sift.max_num_features = self.max_features
            for (model, params, _w, _h), names in groups.items():
                reader = pycolmap.ImageReaderOptions()
                reader.camera_model = model
                reader.camera_params = ",".join(repr(p) for p in params)
                pycolmap.extract_features(self.database, self.image_dir, image_names=names,
                                          camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                                          extraction_options=extraction, device=pycolmap.Device.cpu)
        bar.update(1)
        matching = pycolmap.FeatureMatchingOptions()
        matching.num_threads = self.num_threads
        matching.use_gpu = False
        verification = pycolmap.TwoViewGeometryOptions()
        verification.ransac.random_seed = self.seed
        verification.ransac.num_threads = 1
        # Rendered images carry no watermarks; still images of a static robot
        # would otherwise be mistaken for one.
        verification.detect_watermark = False
        with self._timer("SfM: matching and verification"):
            if self.pairs is None:
                pycolmap.match_exhaustive(self.database, matching_options=matching,
                                          verification_options=verification, device=pycolmap.Device.cpu)
            elif self.pairs:
                listing = self._dir / "pairs.txt"
                listing.write_text("".join(f"{a}.png {b}.png\n" for a, b in self.pairs), encoding="utf-8")
                pairing = pycolmap.ImportedPairingOptions()
                pairing.match_list_path = listing
                pycolmap.match_image_pairs(self.database, matching_options=matching, pairing_options=pairing,
                                           verification_options=verification, device=pycolmap.Device.cpu)
        bar.update(1)
        bar.close()

    # -- incremental mapping ----------------------------------------------

    def _mapping_options(self) -> Any:
        pycolmap = _pycolmap()

        opt = pycolmap.IncrementalPipelineOptions()
        # One thread: with more, Ceres sums a large bundle adjustment's terms
        # in a varying order and the same seed gives a (slightly) different model.
        opt.num_threads = 1
        opt.random_seed = self.seed
        opt.multiple_models = True
        # The calibration is known: intrinsics stay fixed.
        opt.ba_refine_focal_length = False
        opt.ba_refine_principal_point = False
        opt.ba_refine_extra_params = False
        opt.mapper.abs_pose_refine_focal_length = False
        opt.mapper.abs_pose_refine_extra_params = False
        opt.mapper.num_threads = 1
        opt.mapper.random_seed = self.seed
        opt.triangulation.random_seed = self.seed
        opt.extract_colors = False
        # COLMAP's FAQ settings for faster incremental mapping of larger sets:
        # global bundle adjustment less often and with fewer iterations.
        opt.ba_global_frames_ratio = 1.2
        opt.ba_global_points_ratio = 1.2
        opt.ba_global_max_num_iterations = 20
        return opt

    def reconstruct(self, scale: ScaleReference | None = None) -> SfmResult:
        """Incremental structure from motion; the largest model's registered images.

        With ``scale`` the model is scaled so that the two reference images'
        camera centres are ``scale.distance`` apart (both must be registered
        in the largest model, else :class:`~mutloc.errors.NoSolutionError`);
        see also :meth:`SfmResult.scaled`.  Raises
        :class:`~mutloc.errors.NoSolutionError` when no model is built.
        """
        pycolmap = _pycolmap()

        if scale is not None:
            for n in (scale.a, scale.b):
                if n not in self._images:
                    raise InputError(f"scale reference image {n!r} is not one of the images")
        out = self._dir / "sparse"
        shutil.rmtree(out, ignore_errors=True)
        out.mkdir()
        pycolmap.set_random_seed(self.seed)
        try:
            with self._timer("SfM: incremental mapping"):
                models = pycolmap.incremental_mapping(self.database, self.image_dir, out,
                                                      options=self._mapping_options())
        except RuntimeError as e:  # COLMAP's checks surface as RuntimeError
            raise NoSolutionError(f"structure from motion failed: {e}") from None
        if not models:
            raise NoSolutionError("structure from motion built no model (too few verified matches)")
        rec = max(models.values(), key=lambda r: r.num_reg_images())
        poses = {}
        for img in rec.images.values():
            if img.has_pose:
                poses[img.name[:-4]] = _pose_from_rigid(img.cam_from_world())
        err = float(rec.compute_mean_reprojection_error()) if rec.num_points3D() else float("nan")
        res = SfmResult(poses=poses, images=len(self._images), points=int(rec.num_points3D()), models=len(models),
                        mean_reprojection_px=err, unregistered=sorted(n for n in self._images if n not in poses))
        return res.scaled(scale) if scale is not None else res

    # -- triangulation from given poses -------------------------------------

    def triangulate(self, poses: Mapping[str, Pose], *,
                    min_track: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """COLMAP's point triangulator over the scene's verified matches, with
        the camera poses held fixed.

        ``poses[name]`` is ``T_wc`` (camera -> world) of each image to use;
        the others are left out.  Returns ``(points (n, 3) in that world,
        mean reprojection error (n,) px, track length (n,), colour (n, 3)
        uint8 RGB)``.
        """
        pycolmap = _pycolmap()

        unknown = [n for n in poses if n not in self._images]
        if unknown:
            raise InputError(f"poses for unknown images {unknown[:5]}")
        if len(poses) < 2:
            raise InputError("triangulation needs the poses of at least two images")
        db = pycolmap.Database.open(str(self.database))
        try:
            cameras = db.read_all_cameras()
            images = db.read_all_images()
        finally:
            db.close()
        rec = pycolmap.Reconstruction()
        for cam in cameras:
            rec.add_camera_with_trivial_rig(cam)
        for img in images:
            name = img.name[:-4]
            if name not in poses:
                continue
            im = pycolmap.Image(name=img.name, camera_id=img.camera_id, image_id=img.image_id)
            rec.add_image_with_trivial_frame(im, _rigid_from_pose(poses[name]))
        out = self._dir / "triangulated"
        shutil.rmtree(out, ignore_errors=True)
        out.mkdir()
        pycolmap.set_random_seed(self.seed)
        opt = self._mapping_options()
        opt.image_names = [n + ".png" for n in poses]
        opt.extract_colors = True
        try:
            with self._timer("SfM: triangulation from given poses"):
                rec = pycolmap.triangulate_points(rec, self.database, self.image_dir, out, clear_points=True,
                                                  options=opt, refine_intrinsics=False)
        except RuntimeError as e:
            raise NoSolutionError(f"triangulation failed: {e}") from None
        pts = [p for p in rec.points3D.values() if p.track.length() >= min_track]
        X = np.array([p.xyz for p in pts], float).reshape(-1, 3)
        err = np.array([p.error for p in pts], float)
        length = np.array([p.track.length() for p in pts], int)
        colour = np.array([p.color for p in pts], np.uint8).reshape(-1, 3)
        return X, err, length, colour
