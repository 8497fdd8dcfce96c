"""Digests of the scene inputs the package computes and hands to the engine (test_det_inputs.py).

    PYTHONPATH=<package parent> /usr/bin/python3 tests/python/det_inputs_digest.py

imports whichever ``endophoton`` PYTHONPATH names, builds the native inputs of the cases below (no
run: the bits the engine is given, not what it does with them) and prints one JSON object:
``inputs``, case name -> the sha-256 of everything that case hands the engine (each region's
vertices, triangles, medium coefficients and spectra, fluorophores and EEMs; each light's position,
direction, radius, half angle and spectrum; the endoscope head's body; the rig's transform; the
placement check's warnings; the camera tally's request of a run with ``view=``); ``package``, the
package it imported; ``guards``, the digests of the processor-dependent functions the package no
longer uses for its inputs (numpy's float64 sin, glibc's exp through ``math``, a BLAS dot product)
over fixed arguments; and ``blas``, the BLAS numpy runs (read from /proc/self/maps). A process
that runs as an older machine (test_det_inputs.py's environment) must print other guards and the
same inputs. Scenes are read as data (examples/, bench/scenes/*.json), never through bench/'s code.
"""
from __future__ import annotations

import json
import math
import os
import sys

import numpy as np

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))

import endophoton as ep  # noqa: E402
from bit_digest import sha256  # noqa: E402  (beside this file)
from endophoton import media, meshes, placement  # noqa: E402
from endophoton.sources import source_from_dict  # noqa: E402
from endophoton.sweep import driver  # noqa: E402
from endophoton.view import nee  # noqa: E402

#: Tilts, degrees: the paper's sweep (0-55 every 5), a few awkward ones, and tilts whose sine (7.84,
#: -24.78, 29.37) or cosine (47.56, -67.84, 82.24) glibc 2.36 rounds differently with and without FMA
#: (of the tilts -89 to 89 every 0.01 degrees, 14 sines and 10 cosines differed on this machine).
BETAS_DEG = [float(b) for b in range(0, 60, 5)] + [1e-7, 17.123456789, 89.99]
BETAS_DEG += [7.84, -24.78, 29.37, 47.56, -67.84, 82.24]
#: Wavelengths a spectral run samples, nm: the visible every nm, and the table's ends.
WAVELENGTHS_NM = np.concatenate([np.arange(400.0, 701.0, 1.0), [250.0, 333.3, 999.9, 1000.0]])


def scene_inputs(scene) -> dict:
    """What Scene.to_native hands the engine: units, ambient index and every region's arrays."""
    regions = [
        dict(
            name=r.name,
            priority=int(r.priority),
            medium=r.medium.native_args(),
            vertices=np.asarray(r.vertices),
            triangles=np.asarray(r.triangles),
            fluorophores=[
                (f.name, f.d, f.c, f.eem.excitation_nm, f.eem.emission_nm, f.eem.values) for f in r.fluorophores
            ],
        )
        for r in scene.regions
    ]
    return dict(unit_cm=float(scene.unit_cm), ambient_n=float(scene.ambient_n), regions=regions)


def source_inputs(source, unit_cm: float) -> dict:
    """What ep.run hands the engine for a source: its lights and its body; a rig's transform too."""
    out = dict(lights=source.native_lights(unit_cm), body=source.native_body(unit_cm))
    if isinstance(source, ep.EndoscopeRig):
        out["transform"] = np.asarray(source.transform)
    return out


def run_inputs(scene, source) -> dict:
    """A run's inputs: the scene's, the source's and the placement check's warnings."""
    return dict(
        scene=scene_inputs(scene),
        source=source_inputs(source, scene.unit_cm),
        warnings=placement.check_rig(scene, source),
    )


def scene_file(*path: str):
    """The scene and source of a SCENE.json file under the repository, read as the CLI reads them."""
    path = os.path.join(ROOT, *path)
    with open(path, encoding="utf-8") as f:
        data = json.load(f)
    return ep.Scene.from_dict(data, base_dir=os.path.dirname(path)), source_from_dict(data["source"])


def rig_poses() -> list:
    """EndoscopeRig.from_beta over BETAS_DEG for three surfaces (the sweep's pose), and a rig from a
    scaled, rotated transform: each rig's transform, lights, body and camera."""
    surfaces = [
        dict(distance=1.0, point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0)),
        dict(distance=0.01, point=(0.05, 0.0, -0.023), normal=(0, 0, 1), tilt_axis=(0, 1, 0)),
        dict(distance=0.73, point=(0.1, -0.2, 0.3), normal=(0.3, -0.2, 0.9), tilt_axis=(1.0, 0.5, 0.0)),
    ]
    rigs = [ep.EndoscopeRig.from_beta(b, **s) for s in surfaces for b in BETAS_DEG]
    T = np.array([[0.0, -2.0, 0.0, 0.3], [1.5, 0.0, 0.1, -0.2], [0.0, 0.3, 3.0, 1.1], [0.0, 0.0, 0.0, 1.0]])
    rigs.append(ep.EndoscopeRig(transform=T))
    return [(source_inputs(r, 1.0), r.camera("cm"), r.light_positions("mm")) for r in rigs]


def media_inputs() -> dict:
    """Media's coefficients: every preset's, tissues of other parameters, the power laws at
    WAVELENGTHS_NM and through two points."""
    tissues = [
        media.tissue(blood_fraction=0.02, saturation=0.75, a_cm=20.0, b=1.1),
        media.tissue(blood_fraction=0.5, saturation=0.1, a_cm=3.3, b=3.9, g=0.8, background_mua_cm=0.1),
    ]
    return dict(
        presets={name: media.preset(name).native_args() for name in media.preset_names()},
        tissues=[m.native_args() for m in tissues],
        scattering=[
            media.reduced_scattering(WAVELENGTHS_NM, a, b) for a, b in ((18.9, 1.286), (9.22, 0.845), (1.0, 4.0))
        ],
        scattering_at_one=[media.reduced_scattering(w, 18.9, 1.286) for w in (433.0, 617.5)],
        blood=[media.blood_mua(WAVELENGTHS_NM, s) for s in (0.0, 0.513, 0.672, 1.0)],
        through=[
            media.power_law_through(p, q) for p, q in (((300.0, 14.2), (800.0, 6.2)), ((410.0, 33.0), (690.0, 12.5)))
        ],
    )


def mesh_inputs() -> list:
    """Generated meshes: spheres, ellipsoids and half ellipsoids of several sizes and resolutions,
    and the sweep's default flat scene with its polyp dome and bowl in three units."""
    out = [
        meshes.uv_sphere((0.1, -0.2, 0.3), 0.7),
        meshes.ellipsoid((1.0, 2.0, -3.0), (0.4, 0.25, 0.15), n_lat=40, n_lon=96),
        meshes.half_ellipsoid((0.0, 0.0, -1e-4), (0.3, 0.3, 0.2), n_lat=17, n_lon=63),
        meshes.half_ellipsoid((0.2, 0.1, 0.0), (0.5, 0.2, 0.3), n_lat=5, n_lon=7, upper=False),
    ]
    flats = [driver.default_flat_scene(unit=u, polyp=p) for u in ("m", "cm", "mm") for p in ("dome", "embedded")]
    return out + [scene_inputs(s) for s in flats]


def view_inputs(colon, colon_rig) -> list:
    """What ep.run(..., view=...) hands the engine's camera tally (nee.camera_view_options: the
    pinhole frame, tan of the half field, the pixels' solid angles, the channel tables) for the colon
    scene: its rig's own camera at 256 x 256 (view=True), the rig's camera from the poses at
    BETAS_DEG below 80 degrees (beyond, the lens lies in the colon's wall), and cameras from
    SCENE.json's camera object with other fields, lights and filters."""
    photons = 1000
    out = [nee.camera_view_options(colon, colon_rig, photons, True)]
    surface = dict(distance=0.01, point=(0.05, 0.0, -0.023), normal=(0, 0, 1), tilt_axis=(0, 1, 0))
    for beta in (b for b in BETAS_DEG if abs(b) < 80.0):
        rig = ep.EndoscopeRig.from_beta(beta, **surface)
        out.append(nee.camera_view_options(colon, rig, photons, dict(width=24, height=17, n_batches=10)))
    cameras = [
        dict(position=(0.05, 0.01, 0.03), look_at=(0.05, 0.0, -0.023), up=(0, 1, 0), fov_deg=73.3),
        dict(position=(0.2, -0.1, 0.4), look_at=(0.0, 0.02, -0.03), up=(0.1, 0.0, 1.0), fov_deg=17.0),
        dict(position=(0.0, 0.0, 0.05), look_at=(0.01, 0.0, -0.02), up=(0, 1, 0), fov_deg=179.0),
    ]
    views = [
        dict(width=33, height=21),
        dict(width=16, height=40, excitation="blue", white_balance="excitation"),
        dict(width=20, height=20, emission_filter=500.0, white_balance=None),
    ]
    for camera, view in zip(cameras, views):
        out.append(nee.camera_view_options(colon, colon_rig, photons, dict(view, camera=camera)))
    return out


def input_cases() -> dict:
    """Case name -> the inputs the package computes for it."""
    seed, seed_source = scene_file("examples", "seed_tissue.json")
    colon, colon_rig = scene_file("bench", "scenes", "colon.json")  # the paper's scene: rig at 20 degrees
    spectral, spectral_rig = scene_file("examples", "spectral_colon.json")
    sources = [
        ep.ConeSource(position=(0.1, 0.2, 0.5), direction=(1.0, 2.0, -3.0), half_angle_deg=37.3, radius=0.2),
        ep.DiskSource(position=(0, 0, 1), direction=(0.3, 1e-3, -7.0), radius=0.05),
        ep.PencilSource(position=(0, 0, 1), direction=(1e-300, 3e-301, -5e-300)),
    ]
    return dict(
        seed_tissue=run_inputs(seed, seed_source),
        colon=run_inputs(colon, colon_rig),
        spectral_colon=run_inputs(spectral, spectral_rig),
        rig_poses=rig_poses(),
        sources=[source_inputs(s, 1.0) for s in sources],
        media=media_inputs(),
        meshes=mesh_inputs(),
        colon_view=view_inputs(colon, colon_rig),
    )


def _blas_name() -> str:
    """'openblas' when numpy runs OpenBLAS in this process (its library is mapped), else 'other'."""
    with open("/proc/self/maps", encoding="utf-8") as maps:
        return "openblas" if "openblas" in maps.read().lower() else "other"


def guards() -> dict:
    """Digests of processor-dependent functions over fixed arguments (2e5 each), to show that an
    environment that emulates an older machine takes effect: numpy's float64 sin (its dispatched
    kernels), glibc's exp through math (its FMA variant or not), and a BLAS dot product of long
    vectors (OpenBLAS's kernel)."""
    x = np.random.default_rng(1).uniform(0.0, 2.0 * math.pi, 200_000)
    a, b = np.random.default_rng(2).uniform(-1.0, 1.0, (2, 200, 1000))
    return dict(
        numpy_sin=sha256(np.sin(x)),
        math_exp=sha256([math.exp(-v) for v in x.tolist()]),
        blas_dot=sha256([float(np.dot(u, v)) for u, v in zip(a, b)]),
    )


def main() -> None:
    cases = input_cases()
    out = dict(
        inputs={k: sha256(v) for k, v in cases.items()},
        guards=guards(),
        blas=_blas_name(),
        package=os.path.dirname(os.path.abspath(ep.__file__)),
    )
    json.dump(out, sys.stdout)


if __name__ == "__main__":
    main()
