"""render_view's cancel (issue 36: the add-on's Esc while the endoscope view of a finished run is
rendered) and the block sums of its kernel gather (render._accumulate_sparse)."""

import numpy as np
import pytest

import endophoton as ep
from endophoton.view import render
from test_grids_and_runs import _fluor_scene  # one scene for the cancel tests


@pytest.fixture(scope="module")
def records_result():
    return ep.run(
        _fluor_scene(), ep.EndoscopeRig.from_beta(15, 1.0), photons=2000, seed=3, threads=1, record_escapes=True
    )


def test_a_cancelled_token_ends_the_render_with_none(records_result):
    token = ep.CancelToken()
    token.cancel()
    assert ep.render_view(records_result, width=32, height=32, threads=1, cancel=token) is None


def test_an_uncancelled_token_renders_the_same_view(records_result):
    plain = ep.render_view(records_result, width=32, height=32, threads=1)
    with_token = ep.render_view(records_result, width=32, height=32, threads=1, cancel=ep.CancelToken())
    for name in ("white", "fluorescence"):
        a, b = plain.images[name], with_token.images[name]
        assert a["radiance"].tobytes() == b["radiance"].tobytes() and a["srgb8"].tobytes() == b["srgb8"].tobytes()
    assert plain.candidates == with_token.candidates > 0


def test_cancel_must_be_a_token(records_result):
    with pytest.raises(ValueError, match=r"cancel = .* must be None or an endophoton\.CancelToken"):
        ep.render_view(records_result, width=32, height=32, cancel=True)


def test_block_sums_equal_whole_size_bincounts():
    """_accumulate_sparse adds only the bins a chunk touches: the bits of adding a whole-size
    np.bincount per chunk (an independent recomputation), for chunks of spans anywhere in the array."""
    rng = np.random.default_rng(7)
    size, acc, ref = 5000, {}, np.zeros(5000)
    for lo, hi, n in ((0, 300, 1000), (4000, 5000, 50), (1200, 1201, 3), (0, 1, 0), (2500, 4100, 7000)):
        index = rng.integers(lo, hi, n)
        weights = rng.random(n) * 10.0 ** rng.integers(-8, 8, n)
        render._accumulate_sparse(acc, "k", render._bins(index), weights, size)
        ref = ref + np.bincount(index, weights=weights, minlength=size)[:size]
    assert acc["k"].dtype == ref.dtype and acc["k"].tobytes() == ref.tobytes()
