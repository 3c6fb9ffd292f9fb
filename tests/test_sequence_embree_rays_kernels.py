"""``embree-rays``' compiled bookkeeping (slr_ray.sequence.embree_rays, #46 item 4) against the numpy code
it replaced, on small random inputs: the same answer, bit for bit."""

import numpy as np
import pytest

from slr_ray.sequence.embree_rays import _nearest_corners, _pulse_winners


def _winners_numpy(keys, ranges):
    """The old rule: returns sorted by pulse then range (stable), the first of each pulse."""
    ok = np.flatnonzero(keys >= 0)
    o = np.lexsort((ranges[ok], keys[ok]))
    kk = keys[ok][o]
    return ok[o][np.r_[True, kk[1:] != kk[:-1]]] if len(kk) else ok[:0]


@pytest.mark.parametrize("seed", range(4))
def test_one_return_a_pulse_is_the_nearest_and_the_first_of_equals(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(0, 3000))
    keys = rng.integers(-1, 400, n)
    ranges = rng.integers(1, 20, n).astype(np.float64) / 4  # many equal ranges in one pulse
    win = _pulse_winners(keys, ranges)
    np.testing.assert_array_equal(win, _winners_numpy(keys, ranges))
    assert win.dtype == np.int64
    assert len(_pulse_winners(np.full(5, -1), np.ones(5))) == 0


def _corners_numpy(pts, hit, hitm, first, prims, live):
    index = np.zeros(len(hitm), np.int64)
    for k, (_, faces, offset, _, _) in enumerate(live):
        m = np.flatnonzero(first[hitm] == k)
        if not len(m):
            continue
        corners = faces[prims[hitm[m], k]] + offset
        dist = np.linalg.norm(pts[corners] - hit[m][:, None, :], axis=2) if len(pts) else np.zeros(corners.shape)
        index[m] = corners[np.arange(len(m)), np.argmin(dist, axis=1)]
    return index


@pytest.mark.parametrize("seed", range(4))
def test_each_return_stands_for_its_triangles_nearest_corner(seed):
    rng = np.random.default_rng(seed)
    sizes = [50, 80, 30]
    offsets = np.cumsum([0] + sizes[:-1])
    pts = rng.integers(-20, 20, (sum(sizes), 3)) * 0.5  # coarse: corners often equally near
    live = [(None, rng.integers(0, s, (2 * s, 3)), o, None, None) for s, o in zip(sizes, offsets)]
    rays = 500
    prims = np.column_stack([rng.integers(-1, 2 * s, rays) for s in sizes])
    first = rng.integers(0, 3, rays)
    hitm = np.flatnonzero(prims[np.arange(rays), first] >= 0)
    hit = rng.integers(-20, 20, (len(hitm), 3)) * 0.5
    got = _nearest_corners(pts, hit, hitm, first, prims, live)
    np.testing.assert_array_equal(got, _corners_numpy(pts, hit, hitm, first, prims, live))
    empty = np.zeros((0, 3))  # no union points: the first corner
    np.testing.assert_array_equal(_nearest_corners(empty, hit, hitm, first, prims, live),
                                  _corners_numpy(empty, hit, hitm, first, prims, live))


@pytest.mark.parametrize("n_beams", [1, 16, 64, 40000])
def test_rings_in_azimuth_order_are_lexsorts_order(n_beams):
    from slr_ray.sequence.ring_mesh import _ring_order

    rng = np.random.default_rng(n_beams)
    n = 3000
    b = rng.integers(-1, n_beams + 2, n)  # some not known, some beyond the table: left out
    az = np.round(rng.uniform(-np.pi, np.pi, n), 1)  # many equal azimuths in a ring: they keep their order
    az[:1000] = np.sort(az[:1000])  # a run, as a scan's
    keep = np.flatnonzero((b >= 0) & (b < n_beams))
    order, starts = _ring_order(keep, b, az, n_beams)
    want = keep[np.lexsort((az[keep], b[keep]))]
    np.testing.assert_array_equal(order, want)
    np.testing.assert_array_equal(starts, np.searchsorted(b[want], np.arange(n_beams + 1)))


def test_ratio_widening_takes_each_rings_middle_elevation_as_a_full_sort_does():
    # the ring medians by a partial sort of each ring (was a lexsort of the whole frame): the same
    # widening on rings of odd and even sizes, empty rings and points of no ring
    from slr_ray.sequence.ring_mesh import RATIO_STEP_DEG, ratio_widening
    rng = np.random.default_rng(7)
    for n_rows in (1, 2, 5, 16):
        for n in (0, 1, 9, 400):
            rows = rng.integers(-1, n_rows + 1, n)
            rows[rows == 3] = 4  # an empty ring
            pts = rng.normal(size=(n, 3)) * [10.0, 10.0, 3.0]
            got = ratio_widening(pts, rows, n_rows)
            want = np.ones(max(n_rows, 1))
            el = np.degrees(np.arctan2(pts[:, 2], np.hypot(pts[:, 0], pts[:, 1])))
            med = np.full(n_rows, np.nan)
            for k in range(n_rows):
                e = np.sort(el[rows == k])
                if len(e):
                    med[k] = e[len(e) // 2]
            if n_rows >= 2:
                step = np.abs(np.diff(med))
                want[:-1] = np.where(np.isfinite(step), np.maximum(step / RATIO_STEP_DEG, 1.0), 1.0)
            assert np.array_equal(got, want)
