"""A tracking camera for videos: keeps the hand and the object in view, at a steady distance.

Each frame gets a set of spheres to show (hand sites and object geoms: centres (K, 3) m, radii
(K,) m). The camera looks at the spheres' centre from a fixed direction (azimuth, elevation); the
look-at point follows with an exponential lag, and the distance is the larger of a lagged
distance and the one that fits every sphere in the image around the lagged look-at point, so
both stay in frame at every frame while the view moves without jitter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CameraView:
    """A free camera in MuJoCo's ``MjvCamera`` terms: look-at point (3,) m, distance (m),
    azimuth and elevation (degrees)."""

    lookat: np.ndarray
    distance: float
    azimuth: float
    elevation: float

    def position(self) -> np.ndarray:
        """Camera position (3,) m: ``lookat - distance * forward``, as MuJoCo places it."""
        return self.lookat - self.distance * forward_vector(self.azimuth, self.elevation)


def forward_vector(azimuth: float, elevation: float) -> np.ndarray:
    """Unit viewing direction (3,) of a free camera with these angles (degrees)."""
    az, el = math.radians(azimuth), math.radians(elevation)
    return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


def bounding_center(centers: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Centre (3,) m of the axis-aligned box around spheres (K, 3) m with radii (K,) m."""
    lo = (centers - radii[:, None]).min(axis=0)
    hi = (centers + radii[:, None]).max(axis=0)
    return 0.5 * (lo + hi)


def fit_distance(
    lookat: np.ndarray, centers: np.ndarray, radii: np.ndarray, fovy: float, aspect: float
) -> float:
    """Smallest distance (m) at which a camera aimed at ``lookat`` (3,) sees all the spheres.

    Every sphere lies in the ball of radius R around ``lookat``; that ball subtends a cone of
    half-angle asin(R / d), which fits in the image when its tangent is at most that of the
    narrower half field of view (vertical ``fovy`` degrees, horizontal from ``aspect`` = W / H).
    """
    reach = float(np.max(np.linalg.norm(centers - lookat, axis=1) + radii))
    tan_half = math.tan(math.radians(fovy) / 2.0) * min(1.0, aspect)
    return reach / math.sin(math.atan(tan_half))


class TrackingCamera:
    """Smoothed framing of moving spheres, one ``update`` per video frame.

    Args:
        fovy: vertical field of view of the renderer (degrees; MuJoCo's ``vis.global_.fovy``).
        aspect: image width / height.
        dt: time between frames (s).
        azimuth, elevation: fixed viewing direction (degrees). The defaults look from the
            front-right, slightly from above, like the scene's ``front`` camera.
        margin: distance factor over the tight fit, room for the look-at point's lag.
        tau: time constant (s) of the look-at point's and the zoom-in's lag; zooming out is
            immediate so that nothing leaves the frame.
        min_distance: closest the camera comes (m).
    """

    def __init__(
        self,
        fovy: float,
        aspect: float,
        dt: float,
        azimuth: float = 135.0,
        elevation: float = -25.0,
        margin: float = 1.15,
        tau: float = 0.3,
        min_distance: float = 0.3,
    ) -> None:
        self.fovy = fovy
        self.aspect = aspect
        self.azimuth = azimuth
        self.elevation = elevation
        self.margin = margin
        self.min_distance = min_distance
        self.alpha = 1.0 - math.exp(-dt / tau)  # exponential smoothing weight per frame
        self.view: CameraView | None = None

    def update(self, centers: np.ndarray, radii: np.ndarray) -> CameraView:
        """The view for this frame, given the spheres (K, 3) m, (K,) m to keep in frame."""
        centers = np.asarray(centers, dtype=np.float64)
        radii = np.asarray(radii, dtype=np.float64)
        target = bounding_center(centers, radii)
        if self.view is None:
            lookat, distance = target, 0.0
        else:
            lookat = self.view.lookat + self.alpha * (target - self.view.lookat)
            distance = self.view.distance
        needed = self.margin * fit_distance(lookat, centers, radii, self.fovy, self.aspect)
        needed = max(needed, self.min_distance)
        # Zoom in with a lag (no jitter), zoom out at once (nothing leaves the frame).
        distance = needed if needed >= distance else distance + self.alpha * (needed - distance)
        self.view = CameraView(lookat, distance, self.azimuth, self.elevation)
        return self.view
