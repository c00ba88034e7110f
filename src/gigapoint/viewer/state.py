"""A tab's camera as orbit parameters (target, yaw, pitch, distance, fov) and the moves the controls make.

Every control of the viewer maps to a change of these five numbers; ``camera()`` turns them
into a :class:`gigapoint.Camera` through ``Camera.orbit``. Angles are degrees, with the same
conventions as ``Camera.orbit`` (yaw around +z from +x, pitch positive looks down).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..render.camera import VIEWS, Camera

MIN_FOV, MAX_FOV = 1.0, 150.0


def direction(yaw: float, pitch: float) -> np.ndarray:
    """Unit vector from the target to the eye."""
    y, p = math.radians(yaw), math.radians(pitch)
    return np.array([math.cos(p) * math.cos(y), math.cos(p) * math.sin(y), math.sin(p)])


@dataclass
class OrbitState:
    target: np.ndarray
    yaw: float
    pitch: float
    distance: float
    fov: float = 60.0
    scene_radius: float = 1.0  # bounds the distance and how far the target may wander

    @classmethod
    def fit(cls, bounds, view="auto", width=1280, height=720, fov=60.0, points=None) -> OrbitState:
        """The state of ``Camera.fit`` (``points``: what to frame, ``render.camera.sample_points``)."""
        cam = Camera.fit(bounds, view=view, width=width, height=height, fov=fov, points=points)
        yaw, pitch = VIEWS[view] if isinstance(view, str) else view
        back = np.subtract(cam.eye, cam.target)
        distance = float(np.linalg.norm(back))
        if yaw is None:  # 'auto': the angles it chose, read back from the camera
            yaw = math.degrees(math.atan2(back[1], back[0]))
            pitch = math.degrees(math.asin(max(-1.0, min(1.0, back[2] / distance))))
        lo, hi = np.asarray(bounds[0], np.float64), np.asarray(bounds[1], np.float64)
        radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-6)
        return cls(np.array(cam.target, np.float64), float(yaw), float(pitch), distance, float(fov), radius)

    # --- derived ----------------------------------------------------------------
    @property
    def eye(self) -> np.ndarray:
        return self.target + self.distance * direction(self.yaw, self.pitch)

    def camera(self, width: int, height: int) -> Camera:
        return Camera.orbit(self.target, self.yaw, self.pitch, self.distance, fov=self.fov, width=width, height=height)

    def as_dict(self) -> dict:
        return {"target": [float(v) for v in self.target], "yaw": self.yaw, "pitch": self.pitch, "distance": self.distance, "fov": self.fov}

    # --- moves ------------------------------------------------------------------
    def _clamp(self) -> None:
        self.yaw = math.remainder(self.yaw, 360.0)
        self.pitch = min(90.0, max(-90.0, self.pitch))
        r = self.scene_radius
        self.distance = min(max(self.distance, r * 1e-7, 1e-9), r * 1e4)
        self.fov = min(MAX_FOV, max(MIN_FOV, self.fov))

    def set(self, target=None, yaw=None, pitch=None, distance=None, fov=None) -> None:
        if target is not None:
            self.target = np.asarray(target, np.float64).copy()
        if yaw is not None:
            self.yaw = float(yaw)
        if pitch is not None:
            self.pitch = float(pitch)
        if distance is not None:
            self.distance = float(distance)
        if fov is not None:
            self.fov = float(fov)
        self._clamp()

    def orbit(self, dyaw: float, dpitch: float) -> None:
        """Turn around the target (left drag)."""
        self.yaw += dyaw
        self.pitch += dpitch
        self._clamp()

    def look(self, dyaw: float, dpitch: float) -> None:
        """Turn around the eye (fly mode drag): the eye stays, the target moves."""
        eye = self.eye
        self.yaw += dyaw
        self.pitch += dpitch
        self._clamp()
        self.target = eye - self.distance * direction(self.yaw, self.pitch)

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(right, up, forward) unit vectors of the view."""
        right, up, back = self.camera(16, 16).basis()
        return right, up, -back

    def pan(self, dx: float, dy: float) -> None:
        """Drag the scene by (dx, dy) viewport heights (right and down positive)."""
        right, up, _ = self.basis()
        world = 2.0 * self.distance * math.tan(math.radians(self.fov) / 2)
        self.target = self.target - right * dx * world + up * dy * world

    def zoom(self, factor: float, anchor=None) -> None:
        """Scale the distance by ``factor`` about ``anchor`` (a world point that keeps its pixel)."""
        if anchor is None:
            self.distance *= factor
        else:
            anchor = np.asarray(anchor, np.float64)
            before = self.distance
            self.distance *= factor
            self._clamp()
            f = self.distance / before
            self.target = anchor + (self.target - anchor) * f
            return
        self._clamp()

    def move(self, forward: float, right: float, up: float) -> None:
        """Fly: move eye and target together (forward along the view, up along world z)."""
        r, _, fwd = self.basis()
        self.target = self.target + fwd * forward + r * right + np.array([0.0, 0.0, up])

    def set_pivot(self, point) -> None:
        """New orbit centre; the eye stays where it is."""
        eye = self.eye
        v = eye - np.asarray(point, np.float64)
        d = float(np.linalg.norm(v))
        if not d > 0:
            return
        self.target = np.asarray(point, np.float64).copy()
        self.distance = d
        self.pitch = math.degrees(math.asin(max(-1.0, min(1.0, v[2] / d))))
        if abs(v[0]) + abs(v[1]) > 1e-12 * d:
            self.yaw = math.degrees(math.atan2(v[1], v[0]))
        self._clamp()
