import os
import sys

# The repo root holds the `core` and `blender_addon` packages.
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from core.evaluate.synthetic import sphere_scene  # noqa: E402
from core.solve.problem import Problem  # noqa: E402


@pytest.fixture(scope="module")
def exposed():
    """A fixed light, and a different exposure and white balance per photo (3 gains per view)."""
    scene = sphere_scene(
        varying_light=False, n_views=6, height=60, width=80, texture_size=32, seed=5, noise=0.002, textured=True
    )
    gains = np.exp(0.3 * np.random.default_rng(1).standard_normal((6, 3)))
    p = scene.problem
    problem = Problem(
        [im * g for im, g in zip(p.images, gains)],
        p.masks,
        p.normals,
        uv=p.uv,
        texture=p.texture,
        view_weight=p.view_weight,
    )
    return scene, problem, gains
