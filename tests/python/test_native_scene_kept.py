"""Scene.to_native keeps the engine scene while the scene's content is unchanged (speed only).

A sweep of runs over one scene then builds the meshes' checks, the BVH and the per-cube triangle
caches once, and so does a new Scene of the same content (the add-on exports one per run). The kept engine scene must give the same bits as a freshly built one -- its cube
caches are warm from the earlier runs, which must not matter -- and any change of content, in
place or by replacement, must build anew, giving what a scene built with that content gives.
"""
from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest

import endophoton as ep

from cli_helpers import bench_scene

from physics_helpers import run_physics as physics  # noqa: E402


def run(scene, rig, **kw):
    return physics(ep.run(scene, rig, photons=2000, threads=2, seed=11, record_escapes=True, **kw))


@pytest.fixture(scope="module")
def colon():
    return bench_scene("colon")


@pytest.mark.slow
def test_kept_scene_gives_the_bits_of_a_fresh_one(colon):
    scene, rig = colon
    first = run(scene, rig)
    native = scene.to_native()
    assert scene.to_native() is native  # kept
    again = run(scene, rig)  # on the kept engine scene, its cube caches warm
    assert scene.to_native() is native
    same_scene, same_rig = bench_scene("colon")  # another Scene, the same content: takes the kept one
    assert same_scene.to_native() is native
    ep.forget_native_scenes(same_scene)
    fresh_scene, fresh_rig = bench_scene("colon")
    assert fresh_scene.to_native() is not native  # built anew
    fresh = run(fresh_scene, fresh_rig)
    assert first == again == fresh
    assert len(first["escapes"]["weight"]) > 100
    assert scene.to_native() is native  # its own kept one stays until dropped or forgotten
    ep.forget_native_scenes(scene)
    assert scene.to_native() is not native


def test_any_change_of_content_builds_anew(colon):
    scene, rig = copy.deepcopy(colon)
    before = run(scene, rig)
    native = scene.to_native()

    # In place: the polyp's vertices moved by 1 % about their centre.
    polyp = scene.region("polyp")
    c = polyp.vertices.mean(axis=0)
    polyp.vertices[:] = c + (polyp.vertices - c) * np.float32(1.01)
    assert scene.to_native() is not native
    moved = run(scene, rig)
    other, other_rig = bench_scene("colon")
    o = other.region("polyp")
    o.vertices[:] = c + (o.vertices - c) * np.float32(1.01)
    ep.forget_native_scenes()  # `other` must build its own engine scene
    assert moved == run(other, other_rig) and moved != before

    # By replacement: the tissue's medium, then the polyp's fluorophores.
    native = scene.to_native()
    tissue = scene.regions[0]
    tissue.medium = ep.Medium(mua=tissue.medium.mua * 2, mus=tissue.medium.mus, g=tissue.medium.g, n=tissue.medium.n)
    assert scene.to_native() is not native
    native = scene.to_native()
    polyp.fluorophores = polyp.fluorophores[:1]
    assert scene.to_native() is not native
    native = scene.to_native()
    assert scene.to_native() is native


def test_a_scene_with_a_kept_engine_scene_pickles_without_it(colon):
    scene, _ = colon
    native = scene.to_native()
    back = pickle.loads(pickle.dumps(scene))
    assert "_native" not in back.__dict__
    assert back.native_key() == scene.native_key()
    ep.forget_native_scenes()  # else `back` may take the engine scene kept for its content
    assert back.to_native() is not native


def test_forget_native_scenes_names_a_bad_argument(colon):
    scene, _ = colon
    native = scene.to_native()
    with pytest.raises(TypeError, match=r"scenes\[1\] = 'colon' must be an endophoton.Scene"):
        ep.forget_native_scenes(scene, "colon")
    assert scene.to_native() is native  # nothing forgotten before the error
