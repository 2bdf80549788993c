"""The simulated camera renders the truth faithfully: positions, areas, boards, optics, noise."""
from __future__ import annotations

import threading

import numpy as np
import pytest

from cell.clock import ManualClock
from cell.errors import ConfigError
from cell.vision import CameraModel, ChessBoard, CircleGridBoard, Distortion, Intrinsics, Pose
from drivers.camera import CameraError
from drivers.camera.sim import (Fiducial, Optics, SimCamera, _axis_entries, _disc_coverage, _grey_frame,
                                _pool, _radial_scale, _roi, _sample_planes, render, render_float,
                                render_radiance)
from drivers.camera.sim_noise import NoiseAhead

NADIR = CameraModel.nadir(128, 128, 1.0, height_mm=1000.0)
TILTED = CameraModel(Intrinsics(900.0, 900.0, 66.0, 61.0, 128, 128),
                     Pose(900.0, (0.0, 0.0), yaw_deg=20.0, tilt_x_deg=3.0),
                     Distortion(-0.1, 0.0, 0.001, 0.0))


def _image_outline_centroid_and_area(model, x, y, r):
    """Area centroid and area of the disc's image, from its projected outline (shoelace)."""
    t = np.linspace(0, 2 * np.pi, 4000, endpoint=False)
    q = model.project(np.column_stack([x + r * np.cos(t), y + r * np.sin(t)]))
    a, b = q, np.roll(q, -1, axis=0)
    cross = a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1]
    area = cross.sum() / 2
    return (a + b).T @ cross / (6 * area), abs(area)


@pytest.mark.parametrize("model", [NADIR, TILTED], ids=["nadir", "tilted"])
def test_disc_is_rendered_where_it_is_with_its_area(model):
    rng = np.random.default_rng(0)
    optics = Optics(noise_sigma=0.0, blur_sigma_px=0.0, background=0.0, contrast=100.0)
    vv, uu = np.mgrid[0:128, 0:128]
    for _ in range(8):
        x, y = rng.uniform(-5, 5, 2)
        img = render_float(model, [Fiducial(x, y, 8.0)], optics) / 100.0
        centre = np.array([(img * uu).sum(), (img * vv).sum()]) / img.sum()
        truth, area = _image_outline_centroid_and_area(model, x, y, 8.0)
        assert np.allclose(centre, truth, atol=0.002)
        assert img.sum() == pytest.approx(area, rel=1e-3)
    if model is NADIR:                     # straight down: the image centroid is the centre
        assert np.allclose(truth, model.project([(x, y)])[0], atol=1e-9)


def test_blur_keeps_the_mean_and_softens_the_edge():
    sharp = render_radiance(NADIR, [Fiducial(0.2, 0.1, 10.0)], Optics(blur_sigma_px=0.0))
    soft = render_radiance(NADIR, [Fiducial(0.2, 0.1, 10.0)], Optics(blur_sigma_px=2.0))
    assert soft.sum() == pytest.approx(sharp.sum(), rel=1e-6)
    assert np.abs(np.diff(soft, axis=1)).max() < 0.5 * np.abs(np.diff(sharp, axis=1)).max()


def test_lighting_and_noise():
    flat = Optics(noise_sigma=0.0, gain=1.5, offset=10.0, gradient=(0.2, 0.0))
    img = render_float(NADIR, [], flat)
    assert img[64, 0] == pytest.approx(1.5 * 0.8 * 50.0 + 10.0)
    assert img[64, 127] == pytest.approx(1.5 * 1.2 * 50.0 + 10.0)
    noisy = render(NADIR, [], Optics(noise_sigma=5.0), np.random.default_rng(1))
    assert noisy.dtype == np.uint8 and noisy.std() == pytest.approx(5.0, rel=0.05)
    bright = render(NADIR, [Fiducial(0.0, 0.0, 10.0)], Optics(contrast=400.0, noise_sigma=0.0))
    assert bright.max() == 255                                 # over-exposure clips


def test_boards_are_rendered_on_the_plane():
    chess = ChessBoard(5, 4, origin_mm=(-20.0, -15.0), square_mm=10.0)
    img = render(NADIR, [chess], Optics(noise_sigma=0.0, blur_sigma_px=0.0))
    u, v = NADIR.project([(-25.0, -20.0)])[0]                 # inside the black corner square
    assert img[int(round(v)), int(round(u))] == 30
    u, v = NADIR.project([(-15.0, -20.0)])[0]                 # its white neighbour
    assert img[int(round(v)), int(round(u))] == 220
    grid = CircleGridBoard(4, 3, origin_mm=(-15.0, -10.0), pitch_mm=10.0, radius_mm=3.0)
    img = render(NADIR, [grid], Optics(noise_sigma=0.0, blur_sigma_px=0.0))
    for x, y in grid.points_mm():
        u, v = NADIR.project([(x, y)])[0]
        assert img[int(round(v)), int(round(u))] == 30


def test_camera_frames_carry_the_truth_and_are_repeatable():
    scene = [Fiducial(3.0, -2.0, 6.0, "tool"), Fiducial(-20.0, 15.0, 5.0, "part")]
    cams = [SimCamera(NADIR, lambda: scene, seed=5, clock=ManualClock()) for _ in range(2)]
    frames = []
    for cam in cams:
        with cam:
            frames.append([cam.grab() for _ in range(2)])
    assert np.array_equal(frames[0][1].image, frames[1][1].image)       # same seed, same noise
    assert not np.array_equal(frames[0][0].image, frames[0][1].image)   # fresh noise per frame
    meta = frames[0][0].metadata
    assert [f["kind"] for f in meta["fiducials"]] == ["tool", "part"]
    assert np.allclose(meta["fiducials_px"], NADIR.project([(3.0, -2.0), (-20.0, 15.0)]))


def test_scene_is_read_at_every_grab():
    where = {"x": 0.0}
    cam = SimCamera(NADIR, lambda: [(where["x"], 0.0, 5.0, "tool")], clock=ManualClock())
    with cam:
        first = cam.grab().metadata["fiducials_px"][0]
        where["x"] = 10.0
        second = cam.grab().metadata["fiducials_px"][0]
    assert second[0] - first[0] == pytest.approx(10.0)


@pytest.mark.parametrize("item, match", [
    ((1.0, 2.0), "scene item 0"),
    ((1.0, 2.0, -3.0, "tool"), r"scene item 0 .* radius > 0"),
    ((float("nan"), 2.0, 3.0, "tool"), "finite"),
    ("fiducial", "scene item 0"),
])
def test_bad_scene_items_are_named_and_change_nothing(item, match):
    _check_grab_fails_cleanly(lambda: [item], match)


def test_scene_that_is_not_a_list():
    _check_grab_fails_cleanly(lambda: 42, "scene must be a list")


def _check_grab_fails_cleanly(scene, match):
    scenes = [scene]                                  # the scene now: the bad one, then none
    cam = SimCamera(NADIR, lambda: scenes[-1](), clock=ManualClock())
    with cam:
        with pytest.raises(CameraError, match=match):
            cam.grab()
        scenes.append(lambda: [])
        assert cam.grab().index == 0


@pytest.mark.parametrize("kwargs, match", [
    (dict(optics={"noise": 1.0}), "unknown keys"),
    (dict(optics={"supersample": 0}), "supersample"),
    (dict(optics={"gradient": (2.0, 0.0)}), "gradient"),
    (dict(optics={"blur_sigma_px": -1.0}), "blur_sigma_px"),
    (dict(model={"pose": {"height_mm": 1.0}}), "intrinsics"),
    (dict(scene=[Fiducial(0, 0, 1)]), "callable"),
])
def test_bad_construction(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        SimCamera(**kwargs)


def test_default_frame_is_1_3_megapixels():
    with SimCamera(clock=ManualClock()) as cam:
        assert cam.grab().image.shape == (1024, 1280)


def test_blurring_only_the_rendered_regions_equals_blurring_the_frame():
    import cv2
    scene = [Fiducial(0.0, 0.0, 6.0), Fiducial(9.0, 4.0, 5.0),            # overlapping boxes
             Fiducial(-61.0, 30.0, 8.0),                                  # cut by the edge
             CircleGridBoard(3, 3, origin_mm=(20.0, -50.0), pitch_mm=8.0, radius_mm=2.0)]
    sharp = render_radiance(NADIR, scene, Optics(blur_sigma_px=0.0))
    full = cv2.GaussianBlur(sharp, (0, 0), 1.3, borderType=cv2.BORDER_REPLICATE)
    assert np.allclose(render_radiance(NADIR, scene, Optics(blur_sigma_px=1.3)), full, atol=1e-6)


def test_samples_are_the_bilinear_map_of_every_sample_bit_for_bit():
    """_samples interpolates by slices; the same sums written per sample (a gather) give
    the very same floats, for supersampling whose sample places are exact (2, 4) and not (3)."""
    from drivers.camera.sim import _samples
    model = CameraModel.nadir(320, 240, 0.05, centre_mm=(3.0, -2.0))
    box = (101, 57, 163, 120)
    for ss in (1, 2, 3, 4):
        u0, v0, u1, v1 = box
        us, vs = np.arange(u0 - 1, u1 + 2), np.arange(v0 - 1, v1 + 2)
        uu, vv = np.meshgrid(us, vs)
        grid = model.unproject(np.column_stack([uu.ravel(), vv.ravel()])).reshape(len(vs), len(us), 2)
        offs = (np.arange(ss) + 0.5) / ss - 0.5

        def index(lo, hi):
            s = (np.arange(lo, hi + 1)[:, None] + offs).ravel() - (lo - 1)
            i = np.floor(s).astype(int)
            return i, s - i
        iu, fu = index(u0, u1)
        iv, fv = index(v0, v1)
        g = grid[:, iu] * (1 - fu)[None, :, None] + grid[:, iu + 1] * fu[None, :, None]
        want = g[iv] * (1 - fv)[:, None, None] + g[iv + 1] * fv[:, None, None]
        assert np.array_equal(_samples(model, box, ss), want), ss


def test_a_frames_unprojected_pixels_are_each_boxs_bit_for_bit():
    """The frame's pixels unprojected once (_frame_grid) give every box the very floats its
    own unprojection gives; a model whose map is not provably point by point has none."""
    from drivers.camera.sim import _frame_grid, _pixel_grid, _unproject_box
    rng = np.random.default_rng(5)
    for model in (CameraModel.nadir(640, 512, 0.08, centre_mm=(300.0, 12.5)),
                  CameraModel.nadir(320, 240, 0.05, centre_mm=(-0.0, 0.0))):
        assert _frame_grid(model) is not None
        w, h = model.size
        for _ in range(200):
            u0, v0 = int(rng.integers(-1, w)), int(rng.integers(-1, h))
            u1, v1 = int(rng.integers(u0, min(w, u0 + 90) + 1)), int(rng.integers(v0, min(h, v0 + 90) + 1))
            got, want = _pixel_grid(model, u0, v0, u1, v1), _unproject_box(model, u0, v0, u1, v1)
            assert np.array_equal(got, want) and np.array_equal(np.signbit(got), np.signbit(want))
    assert _frame_grid(CameraModel.nadir(64, 48, 0.1, yaw_deg=30.0)) is None
    assert _frame_grid(CameraModel.nadir(64, 48, 0.1, distortion=Distortion(k1=0.01))) is None


def test_pooling_is_numpys_block_mean_bit_for_bit():
    """_pool's 2 x 2 sums in numpy's own order give the floats of numpy's mean over the
    blocks, whatever the block grid (one block row or column included) and the values."""
    from drivers.camera.sim import _pool
    rng = np.random.default_rng(8)
    for rows, cols in [(1, 1), (1, 2), (2, 1), (1, 77), (77, 1), (3, 5), (64, 64), (39, 120)]:
        for ss in (1, 2, 3, 4):
            for _ in range(20):
                cov = rng.random((rows * ss, cols * ss)) * 10.0 ** rng.integers(-9, 9, (rows * ss, cols * ss))
                want = cov.reshape(rows, ss, cols, ss).mean(axis=(1, 3))
                assert np.array_equal(_pool(cov, ss), want), (rows, cols, ss)


def test_render_in_a_work_array_with_noise_drawn_ahead_is_the_same_frame():
    scene = [Fiducial(0.3, -0.2, 3.0, "tool"), Fiducial(4.0, 2.5, 1.5, "part")]
    w, h = NADIR.size
    work = np.empty((h, w))
    for optics in (Optics(), Optics(gain=1.2, offset=4.5, gradient=(0.1, -0.05), noise_sigma=3.0),
                   Optics(noise_sigma=0.0)):
        a, ahead = np.random.default_rng(5), NoiseAhead(np.random.default_rng(5))
        for _ in range(3):
            noise = ahead.take((h, w), optics.noise_sigma) if optics.noise_sigma > 0 else None
            assert np.array_equal(render(NADIR, scene, optics, a),
                                  render(NADIR, scene, optics, out=work, noise=noise))
        ahead.close()


def test_a_camera_painting_on_its_flat_radiance_grabs_renders_frames():
    """A camera whose lighting changes nothing paints each frame on a radiance image kept
    flat between frames: frame after frame (a board, several discs, one cut by the edge,
    none) the very frames :func:`render` gives with the same noise."""
    model = CameraModel.nadir(160, 120, 0.1)
    scenes = [[Fiducial(0.0, 0.0, 2.0), Fiducial(1.5, 0.5, 1.0, "part")],   # overlapping boxes
              [CircleGridBoard(3, 3, origin_mm=(-4.0, -3.0), pitch_mm=3.0, radius_mm=0.8)],
              [], [Fiducial(-7.8, 5.7, 1.5)], [Fiducial(3.0, -2.0, 2.5)]]
    for optics in (Optics(supersample=2), Optics(blur_sigma_px=0.0, background=51.0, noise_sigma=4.0)):
        shown = iter(scenes * 2)
        ref = NoiseAhead(np.random.default_rng(9))
        with SimCamera(model, lambda: next(shown), optics=optics, seed=9, clock=ManualClock()) as cam:
            for scene in scenes * 2:
                want = render(model, scene, optics, noise=ref.take((120, 160), optics.noise_sigma).copy())
                assert np.array_equal(cam.grab().image, want)
        ref.close()


def test_noise_drawn_ahead_is_each_draw_in_order_even_when_the_frame_changes():
    """Frame k is the k-th draw, as drawing each when needed: also when a frame's size or
    sigma differs from the one drawn ahead (the generator is rewound), and after close."""
    def direct(rng, shape, sigma):
        n = rng.standard_normal(shape, dtype=np.float32)
        n *= sigma
        return n
    asks = [((4, 6), 2.0), ((4, 6), 2.0), ((5, 3), 2.0), ((5, 3), 0.5), ((5, 3), 0.5), ((4, 6), 2.0)]
    ref, ahead = np.random.default_rng(11), NoiseAhead(np.random.default_rng(11))
    names = set()
    for shape, sigma in asks:
        got = ahead.take(shape, sigma).copy()
        names |= {t.name for t in threading.enumerate()}
        assert np.array_equal(got, direct(ref, shape, sigma)), (shape, sigma)
    assert "sim-camera-noise" in names
    ahead.close()
    assert np.array_equal(ahead.take((4, 6), 2.0), direct(ref, (4, 6), 2.0))   # the one drawn ahead
    assert np.array_equal(ahead.take((4, 6), 2.0), direct(ref, (4, 6), 2.0))   # drawn in this thread
    ahead.close()


def test_noise_thread_ends_when_idle_and_the_next_take_starts_another():
    """An idle thread ends (an object nobody closes keeps no thread); the draws go on in
    order across the restart."""
    def direct(rng):
        n = rng.standard_normal((3, 5), dtype=np.float32)
        n *= 1.5
        return n
    ref, ahead = np.random.default_rng(4), NoiseAhead(np.random.default_rng(4))
    ahead.idle_s = 0.0                       # end as soon as the frame ahead is drawn
    for _ in range(3):
        assert np.array_equal(ahead.take((3, 5), 1.5), direct(ref))
        thread = ahead._thread
        if thread is not None:
            thread.join(timeout=60)
        assert not thread or not thread.is_alive()
    ahead.close()


def test_sim_camera_frames_do_not_depend_on_the_noise_drawn_ahead():
    """Two cameras with one seed give the same frames; so does one reopened (it starts its
    noise again from the seed, as before drawing ahead)."""
    scene = [Fiducial(0.3, -0.2, 3.0, "tool")]
    a, b = SimCamera(NADIR, lambda: scene, seed=3), SimCamera(NADIR, lambda: scene, seed=3)
    a.open(), b.open()
    first = [a.grab().image.copy() for _ in range(3)]
    assert all(np.array_equal(f, b.grab().image) for f in first)
    a.close(), a.open()
    assert np.array_equal(first[0], a.grab().image)
    a.close(), b.close()


@pytest.mark.parametrize("optics", [
    Optics(), Optics(noise_sigma=40.0, contrast=400.0, background=2.0),   # clipped at both ends
    Optics(gain=1.2, offset=4.5, gradient=(0.1, -0.05), noise_sigma=3.0), Optics(noise_sigma=0.0),
])
def test_the_frame_is_the_rounded_then_clipped_grey_levels(optics):
    """Each pixel is render_float + noise rounded half to even, then clipped to 0..255."""
    scene = [Fiducial(0.3, -0.2, 3.0, "tool"), Fiducial(4.0, 2.5, 1.5, "part")]
    want = render_float(NADIR, scene, optics)
    if optics.noise_sigma > 0:
        noise = np.random.default_rng(9).standard_normal(want.shape, dtype=np.float32)
        noise *= optics.noise_sigma
        want += noise
    want = np.clip(np.rint(want), 0, 255).astype(np.uint8)
    got = render(NADIR, scene, optics, np.random.default_rng(9))
    assert got.dtype == np.uint8 and np.array_equal(got, want)
    if optics.contrast == 400.0:
        assert got.min() == 0 and got.max() == 255


def test_the_one_pass_frame_is_the_rounded_then_clipped_sum_bit_for_bit():
    """A camera painting on its flat radiance makes the frame in one pass (cv2: the sum in
    float64, rounded half to even, saturated): the grey levels of numpy's rint then clip,
    ties, sums a float32 would round otherwise, and both ends included; a radiance beyond
    the one pass's range, or a NaN, takes numpy's passes."""
    rng = np.random.default_rng(2)
    h, w = 24, 32
    noise = (rng.standard_normal((h, w), dtype=np.float32) * np.float32(40.0)).astype(np.float32)
    special = np.array([0.5, 1.5, 2.5, -0.5, -0.6, 254.5, 255.5, 256.0, -300.0, 1e6,
                        2.5 + 1e-12, 2.5 - 1e-12, 0.49999999999999994, 127.5, 128.5])

    def numpy_frame(flat):
        img = flat + noise
        return np.clip(np.rint(img), 0, 255, out=np.empty(img.shape, np.uint8), casting="unsafe")
    for bg in (50.0, 50.5, -3.0, 300.0):
        for extra in (None, 3e9, np.nan):
            flat = np.full((h, w), bg)
            box = (3, 2, 17, 12)                              # u0, v0, u1, v1, inclusive
            inner = flat[2:13, 3:18]
            inner[:] = rng.uniform(-100.0, 400.0, inner.shape)
            inner.flat[:len(special)] = special
            inner[-1, -1] = inner[-1, -1] if extra is None else extra
            zeros = np.zeros((h, w), np.float32)
            for nz in (noise, zeros):
                with np.errstate(invalid="ignore"):          # the NaN's cast, both ways
                    want = numpy_frame(flat) if nz is noise else np.clip(
                        np.rint(flat), 0, 255, out=np.empty((h, w), np.uint8), casting="unsafe")
                    got = _grey_frame(flat, bg, nz, [box], np.empty((h, w)))
                assert got.dtype == np.uint8 and np.array_equal(got, want), (bg, extra)


def test_the_radial_scale_is_the_matrix_products_norm_bit_for_bit():
    """A disc's edge ramp scales by |J n|: taken component by component where each row of
    the Jacobian has one entry and a zero (a nadir camera, turned by quarter turns or
    mirrored), by the matrix product otherwise; the same floats as the matrix product."""
    rng = np.random.default_rng(6)
    dx, dy = rng.normal(0.0, 2.0, (2, 37, 41))
    dx[0, :3] = dy[0, :3] = 0.0                         # the centre itself: rho clamped
    rho = np.hypot(dx, dy)
    jacs = [NADIR.jacobian((0.3, -0.2)), np.array([[0.0, 12.5], [-12.5, 0.0]]),
            np.array([[-3.0, 0.0], [0.0, 7.25]]), np.array([[0.0, 9.0], [4.0, 0.0]]),
            np.array([[12.4, 0.3], [-0.2, 12.6]]), np.array([[0.0, 0.0], [0.0, 5.0]])]
    assert (jacs[0] == np.diag(np.diag(jacs[0]))).all()  # the nadir camera's: one entry a row
    for jac in jacs:
        n = np.stack([dx, dy], axis=-1) / np.maximum(rho, 1e-12)[..., None]
        m = n @ jac.T
        want = np.sqrt(m[..., 0] ** 2 + m[..., 1] ** 2)
        assert np.array_equal(_radial_scale(dx, dy, rho, jac, _axis_entries(jac)), want), jac


def _disc_coverage_everywhere(model, x, y, r, ss, margin):
    """A disc's coverage with the ramp worked out at every sample (what the band saves)."""
    t = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    box = _roi(model, np.column_stack([x + r * np.cos(t), y + r * np.sin(t)]), margin)
    if box is None:
        return None, None
    px, py = _sample_planes(model, box, ss)
    dx, dy = px - x, py - y
    rho = np.hypot(dx, dy)
    n = np.stack([dx, dy], axis=-1) / np.maximum(rho, 1e-12)[..., None]
    m = n @ model.jacobian((x, y)).T
    scale = np.sqrt(m[..., 0] ** 2 + m[..., 1] ** 2)
    return box, _pool(np.clip(0.5 + (r - rho) * scale * ss, 0.0, 1.0), ss)


def test_a_disc_is_covered_as_by_the_ramp_at_every_sample_bit_for_bit():
    """A disc's ramp is worked out only in the band around its edge (and at its centre);
    elsewhere the coverage is the saturated 1 or 0 the ramp gives there: the same floats as
    the ramp at every sample, for discs of any size, cut by the frame's edge, centred on a
    sample, with 2 and 4 samples a pixel, on a nadir camera, and on a turned and a tilted one
    (whose Jacobians take every sample)."""
    rng = np.random.default_rng(8)
    nadir = CameraModel.nadir(160, 120, 0.08, centre_mm=(300.0, 0.0))
    turned = CameraModel.nadir(160, 120, 0.08, centre_mm=(300.0, 0.0), yaw_deg=30.0)
    tilted = CameraModel(Intrinsics(1000.0, 1000.0, 80.0, 60.0, 160, 120),
                         Pose(80.0, (300.0, 0.0), tilt_x_deg=3.0))
    for model in (nadir, turned, tilted):
        for ss in (2, 4):
            margin = 4.0 * 0.9 + 3.0
            centre = _sample_planes(model, (40, 30, 40, 30), ss)[:, 0, 0]   # a sample's own point
            discs = [(*centre, 1.5), (300.0, 0.0, 0.05), (300.0, 0.0, 30.0), (306.1, 4.6, 2.0)]
            discs += [(300.0 + rng.uniform(-7, 7), rng.uniform(-5, 5), rng.uniform(0.2, 4.0))
                      for _ in range(25)]
            for x, y, r in discs:
                want = _disc_coverage_everywhere(model, x, y, r, ss, margin)
                got = _disc_coverage(model, x, y, r, ss, margin)
                assert got[0] == want[0] and np.array_equal(got[1], want[1]), (x, y, r, ss)
