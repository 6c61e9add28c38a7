"""Global image motion between frames (the camera moves): the first stage of light tracking."""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["GlobalMotion"]


class GlobalMotion:
    """Frame-to-frame image translation, by coarse-to-fine Lucas-Kanade.

    Works on a small Gaussian pyramid (levels ``levels``; level 2 is a quarter
    of the size), so it costs about a millisecond at 960x540 and follows
    shifts of a few tens of pixels per frame.  Residuals are clipped, and
    once nearly aligned large ones are ignored, so moving robots and blinking
    lights (a few percent of the image) barely pull on it; a scene without
    texture gives no reliable estimate.  ``update(frame)`` returns ``d`` such that what was at
    pixel ``x`` in the previous frame is at ``x + d`` now.

    A frame whose alignment is not confirmed (see :meth:`update`) returns
    ``hold`` times the previous frame's shift: camera motion is smooth, and a
    camera moving sideways sees the floor and the wall move by different
    amounts, so one translation explains some frames and not the next.
    Dropping the compensation for those frames alone makes a steady pan look
    like jerks to the lights' motion model (measured: a light predicted 60 px
    off after an off period, trust seed 36 of ``bench/trust_sequences.py``).
    ``accept``: see :meth:`update`.
    """

    def __init__(self, levels: tuple[int, ...] = (4, 3, 2), iterations: int = 3, max_shift: float = 60.0,
                 clip: float = 25.0, hold: float = 0.8, accept: float = 0.8) -> None:
        self.levels = tuple(sorted(levels, reverse=True))  # coarse to fine
        self.iterations = int(iterations)
        self.max_shift = float(max_shift)
        self.clip = float(clip)
        self.hold = float(hold)
        self.accept = float(accept)
        self.reset()

    def reset(self) -> None:
        self._templates: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]] = {}
        self._last = np.zeros(2)

    def _pyramid(self, img: np.ndarray) -> dict[int, np.ndarray]:
        out: dict[int, np.ndarray] = {}
        level_img = img
        for lev in range(1, max(self.levels) + 1):
            level_img = cv2.pyrDown(level_img)
            if lev in self.levels:
                out[lev] = level_img.astype(np.float32)
        return out

    def _template(self, img: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None,
                                                 np.ndarray]:
        """Image, its gradients (interior), the inverse of J^T J (None if
        textureless) and J^T J per pixel."""
        m = 3  # the warped image's border is unreliable
        gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3, scale=1 / 8)[m:-m, m:-m]
        gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3, scale=1 / 8)[m:-m, m:-m]
        a = np.array([[float(np.vdot(gx, gx)), float(np.vdot(gx, gy))],
                      [float(np.vdot(gx, gy)), float(np.vdot(gy, gy))]])
        n = gx.size
        # Require some texture in both directions (mean squared gradient of
        # at least ~0.5 grey level per pixel along the weaker one).
        hinv = np.linalg.inv(a) if n and np.linalg.eigvalsh(a)[0] > 0.25 * n else None
        return img, gx, gy, hinv, a / max(n, 1)

    def _residual(self, cur: np.ndarray, tmpl: np.ndarray, d: np.ndarray) -> np.ndarray:
        """``cur(x + d) - tmpl(x)`` on the interior."""
        h, w = cur.shape
        m = np.float32([[1, 0, d[0]], [0, 1, d[1]]])
        warped = cv2.warpAffine(cur, m, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                borderMode=cv2.BORDER_REPLICATE)
        return cv2.subtract(warped, tmpl)[3:-3, 3:-3]

    def _cost(self, r: np.ndarray) -> float:
        """Robust (truncated quadratic) alignment cost."""
        return float(np.mean(np.minimum(r * r, self.clip * self.clip)))

    def update(self, frame: np.ndarray) -> np.ndarray:
        """Shift (px, full resolution) from the previous frame to ``frame``."""
        # Levels too small to hold texture are skipped (small images).
        pyr = {lev: im for lev, im in self._pyramid(frame).items() if min(im.shape) >= 24}
        if not pyr:
            return np.zeros(2)
        levels = sorted(pyr, reverse=True)
        templates = self._templates
        self._templates = {lev: self._template(im) for lev, im in pyr.items()}
        if set(templates) != set(pyr) or any(templates[lev][0].shape != pyr[lev].shape for lev in pyr):
            self._last = np.zeros(2)
            return self._last.copy()
        d = self._last / (2 ** levels[0])  # warm start: camera motion is smooth
        prev_level = levels[0]
        ok = True
        for lev in levels:
            d = d * (2 ** (prev_level - lev))
            prev_level = lev
            tmpl, gx, gy, hinv, _ = templates[lev]
            if hinv is None:
                ok = False
                break
            finest = lev == levels[-1]
            for it in range(self.iterations):
                r = self._residual(pyr[lev], tmpl, d)
                if finest and it > 0:
                    # Redescending weights once nearly aligned: what changed
                    # for real (a light switching, a robot moving) keeps large
                    # residuals and gets no say.
                    r[np.abs(r) > self.clip] = 0.0
                else:
                    # Far from aligned most residuals are large; clipping
                    # bounds the outliers' pull without silencing the rest.
                    np.clip(r, -self.clip, self.clip, out=r)
                step = -hinv @ np.array([float(np.vdot(gx, r)), float(np.vdot(gy, r))])
                d = d + step
                if not np.all(np.isfinite(d)) or np.hypot(*d) * 2**lev > self.max_shift:
                    ok = False
                    break
                if np.hypot(*step) < 0.01:
                    break
            if not ok:
                break
        if ok and np.hypot(*d) * 2**prev_level > 0.1:
            # Accept a shift only if aligning explains the change: it cuts
            # the mismatch to ``accept`` of what it was, or (small shifts,
            # where the mismatch is mostly noise) by at least half what the
            # texture predicts (d^T H d per pixel).  In a scene without
            # texture the only structure is the blinking lights, and their
            # switching must not be taken for camera motion.  (Half, as
            # before 2026-11-27, refused a camera moving sideways -- floor
            # and wall move differently, aligning cuts the mismatch to 0.75
            # -- for its first 23 frames, then took it: the lights' motion
            # model saw the jump as an acceleration, trust seed 36.)
            tmpl, cur, h_px = templates[prev_level][0], pyr[prev_level], templates[prev_level][4]
            c0 = self._cost(self._residual(cur, tmpl, np.zeros(2)))
            c1 = self._cost(self._residual(cur, tmpl, d))
            ok = c1 <= self.accept * c0 or c0 - c1 >= 0.5 * float(d @ h_px @ d)
        self._last = d * (2 ** prev_level) if ok else self.hold * self._last
        return self._last.copy()


