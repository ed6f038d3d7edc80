"""The ground-truth kernels (``sonar/_truth_kernels.py``) against the numpy reference path.

The truth maps must stay what they were: the body of each cell's strongest single
contribution and the elevation span that echoes. The kernel writes them straight into the
maps; here it is compared bit for bit with the pure-numpy path of ``formation._truth_maps``
(``OAS_KERNELS=numpy``) and with the ray-order kernel it replaced, on a full-size thesis frame
and on seeded random rays built to hit the edge cases (ties between bodies, footprints that
leave the image, unlit rays, non-finite elevation spans that send it to the fallback).
"""

import dataclasses

import numpy as np
import pytest

from optiacoustic import Pose, scenes
from optiacoustic.sonar import SonarSpec, simulate_sonar
from optiacoustic.sonar import formation as F
from optiacoustic.sonar.frame import SonarRays

pytest.importorskip("numba")

SPEC = SonarSpec.preset("blueview-p900-90")


def _maps(monkeypatch, mode, spec, rays, threads):
    monkeypatch.setenv("OAS_KERNELS", mode)
    return F._truth_maps(spec, rays, threads)


def _same(a, b):
    for x, y, name in zip(a, b, ("body", "elevation_min", "elevation_max")):
        assert x.dtype == y.dtype and x.shape == y.shape, name
        np.testing.assert_array_equal(x, y, err_msg=name)  # NaN where NaN, every other value equal


def _old_kernel(spec, rays):
    from optiacoustic.sonar import _numba_kernels as kn

    B, J = spec.n_bins, spec.n_beams
    out = np.empty((B, J), np.int16), np.empty((B, J), np.float32), np.empty((B, J), np.float32)
    flat = lambda a: np.ascontiguousarray(a).reshape(-1)  # noqa: E731
    kn.truth_maps(flat(rays.beam_index), flat(rays.footprint_lo), flat(rays.footprint_hi), flat(rays.energy),
                  flat(rays.body), flat(rays.elevation_lo), flat(rays.elevation_hi), float(spec.range_min),
                  1.0 / spec.bin_width, B, J, *out, np.empty((B, J, 4), np.float32), 0, J)
    return out


@pytest.mark.parametrize("threads", [1, 2])
def test_thesis_frame_truth_maps_equal_the_reference(threads, monkeypatch):
    sc = scenes.get("thesis_scene1")
    pose = Pose.look_at(sc.view.eye, sc.view.target)
    monkeypatch.setenv("OAS_KERNELS", "numba")
    rays = simulate_sonar(sc, SPEC, pose, noise=False).rays
    fast = _maps(monkeypatch, "numba", SPEC, rays, threads)
    _same(fast, _maps(monkeypatch, "numpy", SPEC, rays, threads))
    _same(fast, _old_kernel(SPEC, rays))
    assert (fast[0] >= 1).any() and (fast[0] == 0).any() and np.isnan(fast[1]).any()  # targets, seabed, unlit


def _random_rays(spec, n, seed, *, odd_span=False):
    rng = np.random.default_rng(seed)
    beam = rng.integers(0, spec.n_beams, n)
    r = rng.uniform(spec.range_min - 1.0, spec.range_max + 1.0, n)  # some footprints leave the image
    half = rng.exponential(0.05, n)
    lo, hi = r - half, r + half
    energy = rng.exponential(1.0, n) * (rng.random(n) > 0.1)  # a tenth unlit
    body = rng.integers(0, 5, n).astype(np.int32)
    el = rng.uniform(-0.2, 0.2, n)
    el_lo, el_hi = el - 0.01, el + 0.01
    # exact ties: copies of the first rays with another body (the larger id must win)
    k = n // 10
    beam[-k:], lo[-k:], hi[-k:], energy[-k:] = beam[:k], lo[:k], hi[:k], energy[:k]
    body[-k:] = (body[:k] + 1 + rng.integers(0, 3, k)) % 5
    lo[:5], hi[:5] = np.nan, np.nan  # misses
    energy[:5] = 0.0
    if odd_span:
        el_lo[k + 1] = np.nan
        el_hi[k + 2] = np.inf
        el_lo[k + 3] = -np.inf
        energy[k + 1:k + 4] = 1.0
        lo[k + 1:k + 4], hi[k + 1:k + 4] = spec.range_min + 2.0, spec.range_min + 2.1  # inside the image
    shape = (n // spec.n_beams, spec.n_beams)
    f = lambda a: np.asarray(a).reshape(shape)  # noqa: E731
    return SonarRays(range=f(r), energy=f(energy), body=f(body), cos_incidence=f(np.ones(n)), footprint_lo=f(lo),
                     footprint_hi=f(hi), beam_index=f(beam), elevation=f(el), elevation_lo=f(el_lo),
                     elevation_hi=f(el_hi), elevation_step=0.02)


@pytest.mark.parametrize("threads", [1, 2])
def test_random_rays_with_ties_and_edges_equal_the_reference(threads, monkeypatch):
    spec = dataclasses.replace(SPEC, n_beams=64, n_bins=200)
    rays = _random_rays(spec, 64 * 300, seed=3 + threads)
    k = rays.body.size // 10  # the last k rays tie exactly with the first k, with other bodies
    lo = rays.footprint_lo.reshape(-1)[:k]
    assert ((rays.energy.reshape(-1)[:k] > 0) & (lo > spec.range_min) & (lo < spec.range_max)).sum() > 100
    fast = _maps(monkeypatch, "numba", spec, rays, threads)
    _same(fast, _maps(monkeypatch, "numpy", spec, rays, threads))
    _same(fast, _old_kernel(spec, rays))
    assert (fast[0] >= 0).sum() > 1000


def test_non_finite_spans_fall_back_to_the_ray_order_kernel(monkeypatch):
    """A lit ray with a NaN or infinite elevation span (never met in a simulated frame) sends the maps
    to the ray-order kernel, whose rules for those stand (the numpy path lets a NaN win a minimum)."""
    spec = dataclasses.replace(SPEC, n_beams=64, n_bins=200)
    rays = _random_rays(spec, 64 * 300, seed=5, odd_span=True)
    for threads in (1, 2):
        _same(_maps(monkeypatch, "numba", spec, rays, threads), _old_kernel(spec, rays))
    assert np.isinf(rays.elevation_lo).any() and np.isnan(_old_kernel(spec, rays)[1]).any()


def test_direct_kernel_flags_non_finite_spans():
    """The kernel counts lit rays whose span is not finite (the caller then uses the reference rules)."""
    from optiacoustic.sonar import _truth_kernels as tk

    spec = dataclasses.replace(SPEC, n_beams=64, n_bins=200)
    B, J = spec.n_bins, spec.n_beams
    for odd, want in ((False, 0), (True, 3)):
        rays = _random_rays(spec, 64 * 50, seed=9, odd_span=odd)
        flat = lambda a: np.ascontiguousarray(a).reshape(-1)  # noqa: E731
        got = tk.truth_maps_direct(flat(rays.beam_index), flat(rays.footprint_lo), flat(rays.footprint_hi),
                                   flat(rays.energy), flat(rays.body), flat(rays.elevation_lo),
                                   flat(rays.elevation_hi), float(spec.range_min), 1.0 / spec.bin_width, B, J,
                                   np.empty((B, J), np.int16), np.empty((B, J), np.float32),
                                   np.empty((B, J), np.float32), np.empty((B, J), np.float32), 0, J)
        assert got == want


@pytest.mark.parametrize("name", ["thesis_scene1", "cuboids"])
def test_shadow_with_any_number_of_threads_equals_the_numpy_path(name, monkeypatch):
    """Each thread follows its share of the continuation rays into its own mask; the union of the
    masks is the numpy path's mask whatever the number of threads."""
    sc = scenes.get(name)
    pose = Pose.look_at(sc.view.eye, sc.view.target)
    spec = dataclasses.replace(SPEC, n_beams=128, n_bins=300, elevation_samples=64)
    monkeypatch.setenv("OAS_KERNELS", "numpy")
    f = simulate_sonar(sc, spec, pose, noise=False)
    caster = F.caster_for(sc)
    ref = F._shadow_mask(sc, caster, spec, pose, f.rays, f.ground_truth.elevation_min)
    assert ref.sum() > 50
    monkeypatch.setenv("OAS_KERNELS", "numba")
    old = caster.threads
    try:
        for threads in (1, 2, 3):
            caster.threads = threads
            # the multi-cast path (the numpy path's algorithm; the one-cast path: test_shadow_direct.py)
            got = F._shadow_mask(sc, caster, spec, pose, f.rays, f.ground_truth.elevation_min, direct=False)
            assert got.dtype == bool and np.array_equal(got, ref), threads
    finally:
        caster.threads = old


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_grid_ordered_random_rays_in_beam_chunks_equal_the_reference(threads, monkeypatch):
    """Rays in the frame's grid order (ray ``k * n_beams + j`` of beam ``j``) go through the kernel that
    reads only its chunk's beams (``truth_maps_grid``, beams in chunks over the threads): the same maps,
    bit for bit, as the kernel that reads every ray (``truth_maps_direct``, one part) and the ray-order
    kernel, ties and footprints leaving the image included; rays in another order make it decline (-1).
    (On random footprints the numpy path, whose bin coordinates are float32 arithmetic rather than a
    float64 product rounded once, can differ from all three kernels at a bin edge: one cell of 12 800
    with seed 12; never on a simulated frame, see the thesis-frame test.)"""
    from optiacoustic.sonar import _truth_kernels as tk

    spec = dataclasses.replace(SPEC, n_beams=64, n_bins=200)
    B, J = spec.n_bins, spec.n_beams
    flat = lambda a: np.ascontiguousarray(a).reshape(-1)  # noqa: E731
    for seed in (11 + threads, 21 + threads):
        rays = _random_rays(spec, 64 * 300, seed=seed)
        grid = np.broadcast_to(np.arange(spec.n_beams), rays.beam_index.shape).copy()
        rays_grid = dataclasses.replace(rays, beam_index=grid)
        fast = _maps(monkeypatch, "numba", spec, rays_grid, threads)
        assert (fast[0] >= 0).sum() > 1000 and np.isnan(fast[1]).any()
        _same(fast, _old_kernel(spec, rays_grid))
        args = (flat(rays.footprint_lo), flat(rays.footprint_hi), flat(rays.energy), flat(rays.body),
                flat(rays.elevation_lo), flat(rays.elevation_hi), float(spec.range_min), 1.0 / spec.bin_width, B, J)
        direct = np.empty((B, J), np.int16), np.empty((B, J), np.float32), np.empty((B, J), np.float32)
        assert tk.truth_maps_direct(flat(grid), *args, *direct, np.empty((B, J), np.float32), 0, J) == 0
        _same(fast, direct)
        maps = np.empty((B, J), np.int16), np.empty((B, J), np.float32), np.empty((B, J), np.float32)
        assert tk.truth_maps_grid(flat(rays.beam_index), *args, *maps, np.empty((B, J), np.float32), 0, J) == -1
