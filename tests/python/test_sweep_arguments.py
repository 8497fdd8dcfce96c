"""ep.sweep's and ep.run's arguments are checked by name before anything runs (issue 13's contract:
a ValueError naming the argument and its value, never a TypeError or AttributeError from inside)."""
import pytest

import endophoton as ep
from endophoton.sweep import driver as sw

BAD_SWEEP_ARGUMENTS = {
    "betas=None": (dict(betas=None), r"betas = None must be a list of angles"),
    "nested betas": (dict(betas=[[10]]), r"betas\[0\] = \[10\] must be a finite number"),
    "a bool as beta": (dict(betas=[0, True]), r"betas\[1\] = True must be a finite number"),
    "out_dir=5": (dict(out_dir=5), r"out_dir = 5 must be a file path"),
    "out_dir a file": (dict(out_dir=__file__), r"out_dir = .* exists and is not a folder"),
    "rig_kwargs=5": (dict(rig_kwargs=5), r"rig_kwargs = 5 must be None or a dict"),
    "unknown rig keyword": (dict(rig_kwargs={"bogus": 1}), r"rig_kwargs: 'bogus' is not a keyword argument"),
    "run_kwargs a str": (dict(run_kwargs="x"), r"run_kwargs = 'x' must be None or a dict"),
    "unknown run keyword": (dict(run_kwargs={"bogus": 1}), r"run_kwargs: 'bogus' is not a keyword argument of ep.run"),
    "on_beta=5": (dict(on_beta=5), r"on_beta = 5 must be None or a callable"),
    "client an address": (dict(client="tcp://x:1"), r"client = 'tcp://x:1' must be a dask.distributed.Client"),
    "client in run_kwargs": (dict(run_kwargs={"client": 3}), r"run_kwargs\['client'\] = 3 must be a dask"),
    "store=100.0": (dict(store=100.0), r"store = 100.0 must be an integer"),
    "distance a str": (dict(distance="1"), r"distance = '1' must be a finite number"),
    "progress='yes'": (dict(progress="yes"), r"progress = 'yes' must be True, False or a callable"),
    "fluorescent_only='yes'": (dict(fluorescent_only="yes"), r"fluorescent_only = 'yes' must be true or false"),
    "seed_per_beta=1": (dict(seed_per_beta=1), r"seed_per_beta = 1 must be true or false"),
}


def _no_run(*args, **kwargs):
    raise AssertionError("a run started although an argument was bad")


@pytest.mark.parametrize("case", sorted(BAD_SWEEP_ARGUMENTS))
def test_bad_sweep_arguments_are_named_before_any_run(case, monkeypatch, tmp_path):
    kwargs, message = BAD_SWEEP_ARGUMENTS[case]
    monkeypatch.setattr(sw, "run", _no_run)
    args = dict(betas=[10.0], store=100, progress=False)
    args.update(kwargs)
    with pytest.raises(ValueError, match=message):
        ep.sweep(ep.default_flat_scene(), **args)


def test_betas_from_a_generator_are_taken_once():
    res = ep.sweep(ep.default_flat_scene(), betas=(b for b in (0.0, 10.0)), store=50, n_batches=5, progress=False)
    assert list(res.betas) == [0.0, 10.0] and len(res.rows) == 2


def test_run_names_a_client_that_is_not_one_and_a_progress_of_the_wrong_shape():
    scene, rig = ep.default_flat_scene(), ep.EndoscopeRig.from_beta(10.0, 1.0)
    with pytest.raises(ValueError, match=r"client = 'tcp://x:1' must be a dask.distributed.Client"):
        ep.run(scene, rig, photons=10, client="tcp://x:1")
    with pytest.raises(ValueError, match=r"progress = .* must be None or a callable progress\(done, total\)"):
        ep.run(scene, rig, photons=10, progress=lambda: None)
    done = []
    ep.run(scene, rig, photons=10, progress=lambda d, t: done.append(d))  # the right shape runs
    ep.run(scene, rig, photons=10, progress=print)  # a builtin whose signature binds
