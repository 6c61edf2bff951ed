"""The adaptive pass through the job (issue 11): ``run_local_pass(tolerance=...)``, the CLI flag, the EXR's
error-estimate and exact-sample layers, against the all-exact job on the same Cornell box."""

import importlib
import importlib.util

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from sample_loader import sample_module  # noqa: E402


@pytest.fixture
def hlp(extension, scene):
    base = extension.__name__
    return {"job": importlib.import_module(base + ".blender.job"),
            "outputs": importlib.import_module(base + ".blender.outputs")}


def test_adaptive_job_within_tolerance_and_layers(hlp, tmp_path):
    from hemisphere_local_pass.scenes.cornell_box import cornell_box

    box = cornell_box(2)
    values = box.emission + 0.05 + 0.3 * np.random.default_rng(3).random((box.n_polygons, 3))
    sample_module().build(2, resolution=48, domain="FACE", reset=False, radiosity=values)
    job = hlp["job"]
    exact = job.run_local_pass(output=str(tmp_path / "exact.exr"), preview=False)
    assert exact.exact_points is None
    rel = 5e-2
    out = str(tmp_path / "adaptive.exr")
    rep = job.run_local_pass(output=out, preview=False, tolerance=rel)
    h0, h1 = exact.result["irradiance"], rep.result["irradiance"]
    mean = h0[exact.result["alpha"] > 0].mean()
    # the job's tolerance is relative to the mean irradiance, estimated on the coarse grid
    assert rep.tolerance == pytest.approx(rel * mean, rel=0.5)
    assert np.abs(h1 - h0).max() <= rep.tolerance
    assert 0 < rep.exact_points < 48 * 48 and rep.error_estimate <= rep.tolerance
    mask, est = rep.result["exact_sample"], rep.result["error_estimate"]
    assert set(np.unique(mask)) <= {0.0, 1.0}
    # the samples come from core.irradiance's far field with SAMPLE_SHARE of the tolerance (the final ones
    # with FINAL_SHARE): each within its bound (the error_estimate layer there, <= the larger share); the
    # exact job may take its one-call form-factor path (H = pi sum F L, summed in another order): equal to
    # rounding besides
    adaptive = importlib.import_module(job.__name__.rsplit(".", 2)[0] + ".core.adaptive")
    share = max(adaptive.SAMPLE_SHARE, adaptive.FINAL_SHARE)
    assert 0 < share < 1 and (est[mask == 1] <= share * rep.tolerance * (1 + 1e-9) + 1e-12 * h0.max()).all()
    dev = np.abs(h1 - h0).max(axis=-1)[mask == 1]
    assert (dev <= est[mask == 1] + 1e-12 * h0.max()).all(), (dev - est[mask == 1]).max()
    assert "adaptive" in rep.summary()
    layers, *_ = hlp["outputs"].read_exr(out)
    np.testing.assert_allclose(layers["error_estimate"], est, rtol=1e-6, atol=1e-30)
    np.testing.assert_array_equal(layers["exact_sample"], mask)
    with pytest.raises(ValueError, match="tolerance"):
        job.run_local_pass(output=out, tolerance=-1.0)


def test_cli_tolerance_flag(hlp, tmp_path, capsys):
    sample_module().build(1, resolution=12, domain="FACE", reset=False)
    out = str(tmp_path / "cli.exr")
    code = hlp["job"].cli_main(["render", "--output", out, "--tolerance", "0.01", "--quiet", "--no-preview"])
    assert code == 0, capsys.readouterr().err
    assert "adaptive" in capsys.readouterr().out
    layers, *_ = hlp["outputs"].read_exr(out)
    assert layers["exact_sample"].max() == 1.0


def test_adaptive_with_supersampling(hlp, tmp_path):
    """k×k samples per pixel: each sub-sample position is its own image; the pixel layers are means."""
    sample_module().build(2, resolution=20, domain="FACE", reset=False)
    job = hlp["job"]
    exact = job.run_local_pass(output=str(tmp_path / "e.exr"), preview=False, samples=2)
    rep = job.run_local_pass(output=str(tmp_path / "a.exr"), preview=False, samples=2, tolerance=1e-2, workers=1)
    assert np.abs(rep.result["irradiance"] - exact.result["irradiance"]).max() <= rep.tolerance
    frac = rep.result["exact_sample"]
    assert set(np.unique(frac)) <= {0.0, 0.25, 0.5, 0.75, 1.0} and rep.exact_points == int(round(frac.sum() * 4))
    # on 2 workers in a render's kept pool (PoolKeeper.scope): the job's one pool serves the mean probe and
    # all four sub-sample passes (the pass runs in a thread of its own), and the bits are the same
    parallel = importlib.import_module(job.__name__.rsplit(".", 2)[0] + ".core.parallel")
    keeper = parallel.PoolKeeper()
    try:
        with keeper.scope():
            rep2 = job.run_local_pass(output=str(tmp_path / "a2.exr"), preview=False, samples=2, tolerance=1e-2,
                                      workers=2)
    finally:
        keeper.close()
    assert keeper.started == 1 and rep2.workers == 2
    assert rep2.result["irradiance"].tobytes() == rep.result["irradiance"].tobytes()
