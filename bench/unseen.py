"""Twenty-seven scenes made to check the defaults: new pairings of the fixtures' meshes, albedos and lights.

Run by hand (not a test); it renders with Cycles as ``blend_fixtures/make_fixtures.py`` does (about a minute on 2
cores), into ``build/bench/unseen/`` (not kept in the repository)::

    .venv/bin/python bench/unseen.py [--out DIR] [--moving] [--only NAME ...] [--resolution W H]
    .venv/bin/python bench/accuracy_quick.py --fixtures build/bench/unseen --texture-size 0 [--no-ceiling]

The 13 fixtures chose the defaults; these check them on scenes they were not chosen on (the albedo stage's floor was
chosen on the first 17 as well, and checked on the next five; the rule for clipped highlights was made on those 22,
and checked on the last five, all with 8-bit photos and a Principled material; docs/measurements.md).
``--resolution`` renders them larger: at 560x420 and 640x480 they have 68-102 photo pixels per texel on the
lighting stage's 128² texture, more than the fixtures, as large captures have (the lighting stage's ``light_pixels``
was checked on them). ``--moving`` makes six more whose light moves between the photos (:data:`MOVING`, into
``build/bench/moving/``), made to check the albedo stage's weight where the 27 have one such scene.
"""

from __future__ import annotations

import argparse
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "blend_fixtures"))

import bpy  # noqa: E402, F401  (first: it makes bmesh and mathutils importable)
import make_fixtures as fixtures  # noqa: E402

_COMMON = dict(resolution=(256, 192), n_cameras=12, samples=32, texture_size=256, user_mesh="fine")

#: Each is one of the fixtures' meshes with an albedo and a light that the fixtures do not pair with it.
SCENES = {
    "u_torus_coffee": dict(
        _COMMON,
        seed=9100,
        film_transparent=True,
        mesh="torus",
        albedo="photo:coffee.png",
        interpolation="Linear",
        material="diffuse",
        lighting=dict(kind="hdri", hdri=["courtyard"], strength=0.6, rotation_deg=[150.0]),
        photo_format="EXR",
    ),
    "u_rock_patches": dict(
        _COMMON,
        seed=9200,
        mesh="rock",
        albedo="patches",
        interpolation="Closest",
        material="diffuse",
        lighting=dict(kind="hdri", hdri=["city"], strength=0.7, rotation_deg=[0.0]),
        photo_format="PNG",
    ),
    "u_bowl_noise": dict(
        _COMMON,
        seed=9300,
        film_transparent=True,
        mesh="bowl",
        albedo="noise",
        interpolation="Linear",
        material="diffuse",
        lighting=dict(kind="hdri", hdri=["forest"], strength=1.0, rotation_deg=[90.0]),
        photo_format="EXR",
    ),
    "u_suzanne_regions_sun": dict(
        _COMMON,
        seed=9400,
        albedo="regions",
        interpolation="Closest",
        material="principled",
        lighting=dict(
            kind="sun",
            sun_strength=4.0,
            sun_angle_deg=4.0,
            sun_elevation_deg=35.0,
            sun_azimuth_deg=120.0,
            hdri=["studio"],
            strength=0.1,
            rotation_deg=[0.0],
        ),
        photo_format="PNG",
    ),
    "u_stairs_chelsea": dict(
        _COMMON,
        resolution=(320, 240),
        seed=9500,
        mesh="stairs",
        albedo="photo:chelsea.png",
        interpolation="Linear",
        material="diffuse",
        lighting=dict(
            kind="sun",
            sun_strength=3.0,
            sun_angle_deg=3.0,
            sun_elevation_deg=60.0,
            sun_azimuth_deg=-20.0,
            hdri=["sunset"],
            strength=0.4,
            rotation_deg=[200.0],
        ),
        photo_format="JPEG",
        jpeg_quality=90,
    ),
    # Seven more (2026-11-26, eighth session), so that a default is judged on twelve scenes it has not seen.
    "u_suzanne_coffee_forest": dict(
        _COMMON,
        seed=9600,
        film_transparent=True,
        albedo="photo:coffee.png",
        interpolation="Linear",
        material="diffuse",
        lighting=dict(kind="hdri", hdri=["forest"], strength=1.0, rotation_deg=[230.0]),
        photo_format="EXR",
    ),
    "u_torus_checker_sunrise": dict(
        _COMMON,
        seed=9700,
        mesh="torus",
        albedo="checker",
        interpolation="Closest",
        material="diffuse",
        lighting=dict(kind="hdri", hdri=["sunrise"], strength=0.7, rotation_deg=[40.0]),
        photo_format="PNG",
        capture=dict(exposure_ev=0.5, white_balance=0.10),
    ),
    "u_rock_coffee_sun": dict(
        _COMMON,
        seed=9800,
        film_transparent=True,
        mesh="rock",
        albedo="photo:coffee.png",
        interpolation="Linear",
        material="diffuse",
        lighting=dict(
            kind="sun",
            sun_strength=3.0,
            sun_angle_deg=4.0,
            sun_elevation_deg=45.0,
            sun_azimuth_deg=30.0,
            hdri=["interior"],
            strength=0.4,
            rotation_deg=[80.0],
        ),
        photo_format="EXR",
    ),
    "u_bowl_patches_sunset": dict(
        _COMMON,
        resolution=(320, 240),
        seed=9900,
        mesh="bowl",
        albedo="patches",
        interpolation="Closest",
        material="diffuse",
        lighting=dict(kind="hdri", hdri=["sunset"], strength=0.7, rotation_deg=[270.0]),
        photo_format="JPEG",
        jpeg_quality=90,
        capture=dict(jitter_px=1.0),
    ),
    "u_stairs_coffee_interior": dict(
        _COMMON,
        seed=10100,
        mesh="stairs",
        albedo="photo:coffee.png",
        interpolation="Linear",
        material="diffuse",
        lighting=dict(kind="hdri", hdri=["interior"], strength=0.8, rotation_deg=[120.0]),
        photo_format="PNG",
    ),
    "u_suzanne_regions_city": dict(
        _COMMON,
        resolution=(320, 240),
        seed=10200,
        albedo="regions",
        interpolation="Closest",
        material="principled",
        lighting=dict(kind="hdri", hdri=["city"], strength=0.8, rotation_deg=[300.0]),
        photo_format="JPEG",
        jpeg_quality=85,
        capture=dict(exposure_ev=0.5, white_balance=0.10),
    ),
    "u_torus_patches_varying": dict(
        _COMMON,
        seed=10300,
        film_transparent=True,
        mesh="torus",
        albedo="patches",
        interpolation="Closest",
        material="diffuse",
        lighting=dict(kind="hdri_per_view", hdri=["forest", "city"], strength=[0.8, 0.6], rotation_step_deg=137.5),
        photo_format="EXR",
    ),
    # Five more (2026-11-26, eighth session), rendered to check a choice made on the twelve above.
    "u_bowl_chelsea_courtyard": dict(
        _COMMON,
        seed=10400,
        film_transparent=True,
        mesh="bowl",
        albedo="photo:chelsea.png",
        interpolation="Linear",
        material="diffuse",
        lighting=dict(kind="hdri", hdri=["courtyard"], strength=0.7, rotation_deg=[200.0]),
        photo_format="EXR",
    ),
    "u_torus_noise_sun": dict(
        _COMMON,
        seed=10500,
        mesh="torus",
        albedo="noise",
        interpolation="Linear",
        material="diffuse",
        lighting=dict(
            kind="sun",
            sun_strength=3.0,
            sun_angle_deg=4.0,
            sun_elevation_deg=40.0,
            sun_azimuth_deg=100.0,
            hdri=["city"],
            strength=0.3,
            rotation_deg=[30.0],
        ),
        photo_format="PNG",
        capture=dict(exposure_ev=0.5, white_balance=0.10),
    ),
    "u_rock_checker_forest": dict(
        _COMMON,
        seed=10600,
        film_transparent=True,
        mesh="rock",
        albedo="checker",
        interpolation="Closest",
        material="diffuse",
        lighting=dict(kind="hdri", hdri=["forest"], strength=1.0, rotation_deg=[300.0]),
        photo_format="EXR",
    ),
    "u_stairs_patches_sunrise": dict(
        _COMMON,
        resolution=(320, 240),
        seed=10700,
        mesh="stairs",
        albedo="patches",
        interpolation="Closest",
        material="diffuse",
        lighting=dict(kind="hdri", hdri=["sunrise"], strength=0.8, rotation_deg=[60.0]),
        photo_format="JPEG",
        jpeg_quality=90,
        capture=dict(jitter_px=1.0),
    ),
    "u_suzanne_coffee_sun": dict(
        _COMMON,
        seed=10800,
        albedo="photo:coffee.png",
        interpolation="Linear",
        material="principled",
        lighting=dict(
            kind="sun",
            sun_strength=3.5,
            sun_angle_deg=4.0,
            sun_elevation_deg=30.0,
            sun_azimuth_deg=-100.0,
            hdri=["forest"],
            strength=0.3,
            rotation_deg=[0.0],
        ),
        photo_format="PNG",
    ),
    # Five more (2026-11-27, ninth session), rendered to check the albedo stage's floor (docs/measurements.md).
    "u_rock_noise_sunset_sun": dict(
        _COMMON,
        seed=10900,
        film_transparent=True,
        mesh="rock",
        albedo="noise",
        interpolation="Linear",
        material="principled",
        lighting=dict(
            kind="sun",
            sun_strength=3.0,
            sun_angle_deg=3.0,
            sun_elevation_deg=25.0,
            sun_azimuth_deg=200.0,
            hdri=["sunset"],
            strength=0.4,
            rotation_deg=[90.0],
        ),
        photo_format="EXR",
    ),
    "u_bowl_coffee_sun": dict(
        _COMMON,
        seed=11000,
        mesh="bowl",
        albedo="photo:coffee.png",
        interpolation="Linear",
        material="diffuse",
        lighting=dict(
            kind="sun",
            sun_strength=3.0,
            sun_angle_deg=4.0,
            sun_elevation_deg=50.0,
            sun_azimuth_deg=-40.0,
            hdri=["interior"],
            strength=0.4,
            rotation_deg=[0.0],
        ),
        photo_format="PNG",
    ),
    "u_stairs_chelsea_sun": dict(
        _COMMON,
        seed=11100,
        mesh="stairs",
        albedo="photo:chelsea.png",
        interpolation="Linear",
        material="principled",
        lighting=dict(
            kind="sun",
            sun_strength=3.0,
            sun_angle_deg=4.0,
            sun_elevation_deg=35.0,
            sun_azimuth_deg=70.0,
            hdri=["city"],
            strength=0.3,
            rotation_deg=[180.0],
        ),
        photo_format="JPEG",
        jpeg_quality=92,
        capture=dict(exposure_ev=0.4, white_balance=0.08),
    ),
    "u_suzanne_chelsea_courtyard": dict(
        _COMMON,
        seed=11200,
        albedo="photo:chelsea.png",
        interpolation="Linear",
        material="principled",
        lighting=dict(kind="hdri", hdri=["courtyard"], strength=0.8, rotation_deg=[250.0]),
        photo_format="PNG",
    ),
    "u_torus_coffee_sun": dict(
        _COMMON,
        seed=11300,
        mesh="torus",
        albedo="photo:coffee.png",
        interpolation="Linear",
        material="diffuse",
        lighting=dict(
            kind="sun",
            sun_strength=3.0,
            sun_angle_deg=4.0,
            sun_elevation_deg=20.0,
            sun_azimuth_deg=10.0,
            hdri=["studio"],
            strength=0.3,
            rotation_deg=[0.0],
        ),
        photo_format="PNG",
    ),
    "u_torus_chelsea_city": dict(
        _COMMON,
        seed=11400,
        mesh="torus",
        albedo="photo:chelsea.png",
        interpolation="Linear",
        material="principled",
        lighting=dict(kind="hdri", hdri=["city"], strength=0.9, rotation_deg=[40.0]),
        photo_format="PNG",
    ),
    "u_rock_checker_sun": dict(
        _COMMON,
        seed=11500,
        mesh="rock",
        albedo="checker",
        interpolation="Closest",
        material="principled",
        lighting=dict(
            kind="sun",
            sun_strength=3.5,
            sun_angle_deg=4.0,
            sun_elevation_deg=40.0,
            sun_azimuth_deg=120.0,
            hdri=["sunset"],
            strength=0.4,
            rotation_deg=[90.0],
        ),
        photo_format="JPEG",
        jpeg_quality=90,
    ),
    "u_bowl_noise_courtyard": dict(
        _COMMON,
        seed=11600,
        mesh="bowl",
        albedo="noise",
        interpolation="Linear",
        material="principled",
        lighting=dict(kind="hdri", hdri=["courtyard"], strength=1.0, rotation_deg=[20.0]),
        photo_format="PNG",
    ),
    "u_stairs_coffee_sunrise": dict(
        _COMMON,
        seed=11700,
        mesh="stairs",
        albedo="photo:coffee.png",
        interpolation="Linear",
        material="principled",
        lighting=dict(kind="hdri", hdri=["sunrise"], strength=1.0, rotation_deg=[320.0]),
        photo_format="JPEG",
        jpeg_quality=92,
        capture=dict(exposure_ev=0.3, white_balance=0.06),
    ),
    "u_suzanne_regions_forest_sun": dict(
        _COMMON,
        seed=11800,
        albedo="regions",
        interpolation="Closest",
        material="principled",
        lighting=dict(
            kind="sun",
            sun_strength=3.0,
            sun_angle_deg=4.0,
            sun_elevation_deg=55.0,
            sun_azimuth_deg=-100.0,
            hdri=["forest"],
            strength=0.5,
            rotation_deg=[0.0],
        ),
        photo_format="PNG",
    ),
}


def _moving_sun(**kw):
    """torus_varying_sun's light (a sun lamp that turns and climbs between the photos, an HDRI that turns too)."""
    return dict(fixtures.SCENES["torus_varying_sun"]["lighting"], **kw)


#: Six scenes whose light moves between the photos (the 27 have one such), made to check the albedo stage's weight
#: from the sparsity of the changes of colour (2026-11-30, thirty-eighth session; ``--moving``).
MOVING = {
    "m_bowl_patches_sun": dict(
        _COMMON,
        seed=20100,
        film_transparent=True,
        mesh="bowl",
        albedo="patches",
        interpolation="Closest",
        material="diffuse",
        lighting=_moving_sun(hdri=["forest"]),
        photo_format="EXR",
    ),
    "m_rock_coffee_hdri": dict(
        _COMMON,
        seed=20200,
        mesh="rock",
        albedo="photo:coffee.png",
        interpolation="Linear",
        material="diffuse",
        lighting=dict(kind="hdri_per_view", hdri=["courtyard", "sunset"], strength=[0.7, 0.6], rotation_step_deg=137.5),
        photo_format="PNG",
    ),
    "m_stairs_noise_sun": dict(
        _COMMON,
        seed=20300,
        mesh="stairs",
        albedo="noise",
        interpolation="Linear",
        material="diffuse",
        lighting=_moving_sun(hdri=["city"]),
        photo_format="PNG",
    ),
    "m_suzanne_regions_hdri": dict(
        _COMMON,
        seed=20400,
        albedo="regions",
        interpolation="Closest",
        material="principled",
        lighting=dict(kind="hdri_per_view", hdri=["city", "forest"], strength=[0.8, 0.8], rotation_step_deg=97.0),
        photo_format="JPEG",
        jpeg_quality=90,
    ),
    "m_torus_checker_sun": dict(
        _COMMON,
        seed=20500,
        film_transparent=True,
        mesh="torus",
        albedo="checker",
        interpolation="Closest",
        material="diffuse",
        lighting=_moving_sun(hdri=["courtyard"]),
        photo_format="EXR",
    ),
    "m_bowl_chelsea_hdri": dict(
        _COMMON,
        seed=20600,
        film_transparent=True,
        mesh="bowl",
        albedo="photo:chelsea.png",
        interpolation="Linear",
        material="diffuse",
        lighting=dict(kind="hdri_per_view", hdri=["interior", "sunrise"], strength=[0.9, 0.6], rotation_step_deg=137.5),
        photo_format="EXR",
    ),
}


def register(only=None, scenes=None):
    """Make ``scenes`` (default :data:`SCENES`) known to ``make_fixtures``; the names of ``only`` (all if None),
    checked."""
    scenes = SCENES if scenes is None else scenes
    for name, spec in scenes.items():
        fixtures.SCENES[name] = spec
        fixtures._DESCRIPTIONS[name] = f"unseen scene {name} (bench/unseen.py)"
    unknown = sorted(set(only or ()) - set(scenes))
    if unknown:
        raise SystemExit(f"error: no unseen scene {', '.join(unknown)} (bench/unseen.py has {', '.join(scenes)})")
    return list(only or scenes)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", help="default: build/bench/unseen, or build/bench/moving with --moving")
    p.add_argument("--moving", action="store_true", help="the six scenes whose light moves (MOVING), not the 27")
    p.add_argument("--only", nargs="*", choices=list(SCENES) + list(MOVING), help="scenes to make (default: all)")
    p.add_argument(
        "--resolution", nargs=2, type=int, metavar=("W", "H"), help="photo size (default: 256 192, the scenes' own)"
    )
    args = p.parse_args(argv)
    resolution = tuple(args.resolution) if args.resolution else None
    out = args.out or os.path.join(ROOT, "build", "bench", "moving" if args.moving else "unseen")
    for name in register(args.only, MOVING if args.moving else SCENES):
        # Absolute: the scene's photo paths are made relative to the .blend, and a relative --out broke them.
        fixtures.generate(name, os.path.abspath(out), resolution=resolution)
        print("made", os.path.join(os.path.abspath(out), name), flush=True)


if __name__ == "__main__":
    main()
