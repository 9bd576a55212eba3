"""What a rendered target looks like by geometry alone, independent of the renderer: the
reference the camera, render and detector tests judge bearings and occlusion against."""

from __future__ import annotations

import math

from cr_sim.core.geometry import raycast, wrap_angle
from cr_sim.core.render import Scene
import numpy as np


def truth(scene: Scene, pose, k: int) -> dict:
    """Target k seen from ``pose``: true bearing, half-angle of its silhouette (``alpha``), its
    distance, and whether a tall obstacle hides all of it (``hidden``) or none (``clear``)."""
    x, y, th = pose
    rel = scene.centres[k] - np.array((x, y))
    dist = float(np.hypot(*rel))
    r = scene.params.target_radius
    alpha = math.asin(r / dist)
    phi = math.atan2(rel[1], rel[0]) + np.linspace(-0.999, 0.999, 41) * alpha
    d = np.stack((np.cos(phi), np.sin(phi)), axis=1)
    proj = d @ rel
    entry = proj - np.sqrt(np.maximum(r * r - (dist * dist - proj * proj), 0.0))
    t_tall = raycast(x, y, d, scene.tall)
    return {'bearing': wrap_angle(math.atan2(rel[1], rel[0]) - th), 'alpha': alpha,
            'dist': dist, 'clear': bool((t_tall > entry).all()),
            'hidden': bool((t_tall < entry).all())}
