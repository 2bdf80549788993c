"""The fiducial search's shortcuts give the very values (bit for bit) of the plain numpy /
OpenCV calls they stand for: a find's result must not depend on them."""
from __future__ import annotations

import math

import cv2
import numpy as np
from scipy.special import erfc

from cell.vision.fiducial import (_SQRT2, _SQRT2PI, _components, _disc_model, _median, _radii,
                                  edge_ring, estimate_noise)


def test_noise_median_from_histogram_is_np_median():
    rng = np.random.default_rng(3)
    for t in range(300):
        h, w = rng.integers(8, 120, 2)
        big = rng.normal(100, rng.uniform(0, 30), (h + 9, w + 9)).clip(0, 255).astype(np.uint8)
        y, x = rng.integers(0, 9, 2)
        work = big[y:y + h, x:x + w]                       # a view, as a roi is
        d = np.abs(np.diff(work[::2].astype(np.int16), axis=1))
        want = max(0.5, 1.4826 * float(np.median(d)) / _SQRT2)
        assert estimate_noise(work) == want, t


def test_components_on_the_box_match_the_whole_mask():
    rng = np.random.default_rng(5)
    yy, xx = np.mgrid[:90, :110]
    for t in range(300):
        mask = np.zeros((90, 110), np.uint8)
        for _ in range(rng.integers(0, 6)):
            cx, cy, r = rng.uniform(0, 110), rng.uniform(0, 90), rng.uniform(0.3, 15)
            mask[(xx - cx) ** 2 + (yy - cy) ** 2 <= r * r] = 1
        if t % 3 == 0:
            mask |= (rng.random(mask.shape) < 0.01).astype(np.uint8)
        n, labels, stats, cents = cv2.connectedComponentsWithStats(mask, connectivity=8)
        n2, labels2, (u0, v0), stats2, cents2 = _components(mask)
        assert n2 == n
        assert np.array_equal(stats2[1:], stats[1:])
        assert cents2[1:].tobytes() == cents[1:].tobytes()
        if n > 1:
            h, w = labels2.shape
            assert np.array_equal(labels2, labels[v0:v0 + h, u0:u0 + w])


def test_radii_compare_as_hypot_does():
    rng = np.random.default_rng(9)
    for t in range(300):
        uu = np.arange(70.0)[None, :] + rng.integers(0, 500)
        vv = np.arange(60.0)[:, None] + rng.integers(0, 400)
        uc, vc = uu[0, 35] + rng.uniform(-3, 3), vv[30, 0] + rng.uniform(-3, 3)
        exact = np.hypot(uu - uc, vv - vc)
        hit = exact.ravel()[rng.integers(exact.size, size=3)]   # thresholds on exact distances
        ths = [float(hit[0]), float(np.nextafter(hit[1], 0)), float(np.nextafter(hit[2], 99)),
               float(rng.uniform(0, 40))]
        d = _radii(uu - uc, vv - vc, ths)
        for th in ths:
            for op in (np.less, np.less_equal, np.greater, np.greater_equal):
                assert np.array_equal(op(d, th), op(exact, th)), (t, th)
        r = float(rng.uniform(2, 30))
        band = 5.0 + 0.1 * r
        assert np.array_equal(edge_ring(uu, vv, uc, vc, r), np.abs(exact - r) <= band)


def test_median_is_np_median():
    rng = np.random.default_rng(2)
    for n in (1, 2, 3, 10, 11, 400, 401):
        x = rng.normal(size=n)
        assert _median(x) == float(np.median(x))
    assert math.isnan(_median(np.array([1.0, np.nan, 2.0])))


def _reference_model(p, uu, vv, u0, v0):
    """The disc model written out in full, lighting factor and all."""
    uc, vc, r, a, b, s, gx, gy = p
    sgn = 1.0 if s >= 0 else -1.0
    s = abs(s) + 1e-9
    du, dv = uu - uc, vv - vc
    rho = np.sqrt(du * du + dv * dv) + 1e-12
    z = (rho - r) / s
    e = 0.5 * erfc(z / _SQRT2)
    light = 1.0 + gx * (uu - u0) + gy * (vv - v0)
    base = b + a * e
    aphi = a * np.exp(-0.5 * z * z) / (s * _SQRT2PI) * light
    jac = np.column_stack([aphi * du / rho, aphi * dv / rho, aphi, e * light, light,
                           aphi * z * sgn, base * (uu - u0), base * (vv - v0)])
    return base * light, jac


def test_disc_model_matches_the_full_formula():
    rng = np.random.default_rng(1)
    for t in range(60):
        m = int(rng.integers(50, 3000))
        uu, vv = rng.uniform(100, 300, m).round(), rng.uniform(100, 300, m).round()
        u0, v0 = 200.3, 201.7
        flat = t % 2 == 0
        p = np.array([200 + rng.normal(), 201 + rng.normal(), 30 + rng.normal(),
                      rng.choice([-1.0, 1.0]) * 150, 50, rng.normal(),
                      0.0 if flat else rng.normal() * 1e-3, 0.0 if flat else rng.normal() * 1e-3])
        cols = 6 if flat else 8
        f, jac = _disc_model(p, uu, vv, uu - u0, vv - v0, cols)
        f_ref, jac_ref = _reference_model(p, uu, vv, u0, v0)
        assert f.tobytes() == f_ref.tobytes()
        assert np.ascontiguousarray(jac[:, :cols]).tobytes() == jac_ref[:, :cols].tobytes()
