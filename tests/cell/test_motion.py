"""cell.motion.mover: Mover planning and streaming against fake stations, check_mode's reasons and
the recipe check built on it (cell.recipes.motion_check).

The fake stations return fixed per-joint burst delays λ (or, for ``corrected`` bursts, λ
that changes from burst to burst, so each segment's correction can be told apart) and
compute seed 002's corrected velocities Δθ/(T − λ) the way the driver does.
"""
import re
from types import SimpleNamespace

import numpy as np
import pytest

from cell.errors import ConfigError, TrajectoryError
from cell.kinematics import JOINT_NAMES, Scara
from cell.motion.line import TIME_LAWS
from cell.motion.mover import MotionSpec, Mover, check_mode
from cell.recipes import motion_check, parse_recipe
from cell.recipes.store import RecipeStore
from drivers.stations.streaming import StationCommandError

from tests.cell.conftest import REPO_RECIPES

ROBOT = Scara.preset("seed000")
LAM = np.array([0.001, 0.002, 0.003, 0.004])
LAM_SYNC = np.array([0.0005, 0.001, 0.0015, 0.002])
T = 0.01
Q0 = np.array([40.0, 60.0, 0.0, 0.0])
Q1 = ROBOT.ik([238.0, 930.0, -20.0, 0.0])           # the approach point of bracket-a


class Stations:
    def __init__(self, lam=LAM, lam_sync=LAM_SYNC, max_velocity=None, drift_s=0.0):
        mv = {j: 720.0 for j in JOINT_NAMES} | (max_velocity or {})
        self.cfg = SimpleNamespace(station=lambda joint: SimpleNamespace(max_velocity=mv[joint]))
        self.lam, self.lam_sync = np.array(lam, dtype=float), np.array(lam_sync, dtype=float)
        self.drift_s = drift_s                        #: λ grows by this per corrected burst
        self.bases: list[int] = []
        self.corrected: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []   #: (target, Δθ, λ)
        self.streams: list[tuple[str, list]] = []
        self.waits: list[tuple[float, float]] = []

    def burst_delays(self, targets_deg, velocities_deg_s, base=0x200):
        self.bases.append(base)
        return (self.lam_sync if base == 0x400 else self.lam).copy()

    def corrected_velocities(self, targets_deg, deltas_deg, segment_s, hint_s=None):
        lam = self.lam + self.drift_s * len(self.corrected)
        if segment_s <= float(np.max(lam)):
            raise StationCommandError(f"segment time T = {segment_s * 1e3:.6g} ms is not longer "
                                      f"than the delay of j4 λ = {np.max(lam) * 1e3:.6g} ms")
        d = np.asarray(deltas_deg, dtype=float)
        self.corrected.append((np.array(targets_deg, dtype=float), d.copy(), lam))
        return d / (segment_s - lam), lam

    def stream(self, segments, mode="reception", lead_s=None):
        self.streams.append((mode, list(segments)))

    def wait_reached(self, timeout_s, tol=0.02):
        self.waits.append((timeout_s, tol))


def targets(q0, segs) -> np.ndarray:
    return np.array([q0] + [s.target_deg for s in segs])


def velocities(segs) -> np.ndarray:
    return np.array([s.velocity_deg_s for s in segs])


# ------------------------------------------------------------------------------ velocities
def test_corrected_velocities_are_the_step_over_T_minus_each_bursts_lambda():
    st = Stations(drift_s=1e-6)
    segs, rep = Mover(ROBOT, st).plan(Q0, Q1, MotionSpec("corrected", T, "smooth", 120.0))
    assert len(st.corrected) == len(segs) == rep.segments
    lams = np.array([lam for _, _, lam in st.corrected])
    steps = np.diff(targets(Q0, segs), axis=0)
    np.testing.assert_allclose(velocities(segs), steps / (T - lams), rtol=1e-12, atol=0)
    np.testing.assert_allclose([t for t, _, _ in st.corrected], targets(Q0, segs)[1:], atol=0)
    np.testing.assert_allclose([d for _, d, _ in st.corrected], steps, atol=0)
    assert rep.delays_s == pytest.approx(tuple(lams.mean(axis=0)), rel=1e-12)
    assert rep.mode == "corrected" and rep.segment_s == T and rep.duration_s == pytest.approx(
        rep.segments * T)
    assert [s.index for s in segs] == list(range(1, len(segs) + 1))
    assert [s.start_s for s in segs] == pytest.approx([k * T for k in range(len(segs))])
    assert all(s.duration_s == T for s in segs)


@pytest.mark.parametrize("mode, base, lam", [("sync", 0x400, LAM_SYNC), ("none", 0x200, LAM)])
def test_sync_and_none_use_step_over_T_and_the_first_bursts_delays(mode, base, lam):
    st = Stations()
    segs, rep = Mover(ROBOT, st).plan(Q0, Q1, MotionSpec(mode, T, "smooth", 120.0))
    np.testing.assert_allclose(velocities(segs), np.diff(targets(Q0, segs), axis=0) / T, rtol=1e-12)
    assert st.corrected == []
    assert set(st.bases) == {base}
    assert rep.delays_s == tuple(lam)


@pytest.mark.parametrize("mode, stream_mode", [("corrected", "reception"), ("sync", "sync"),
                                               ("none", "reception")])
def test_move_streams_in_the_mode_then_waits(mode, stream_mode):
    st = Stations()
    rep = Mover(ROBOT, st).move(Q0, Q1, MotionSpec(mode, T, "smooth", 120.0), 7.5, 0.001)
    assert [m for m, _ in st.streams] == [stream_mode]
    assert len(st.streams[0][1]) == rep.segments
    assert st.waits == [(7.5, 0.001)]
    np.testing.assert_array_equal(st.streams[0][1][-1].target_deg, Q1)


# ------------------------------------------------------------------------------ segment count
@pytest.mark.parametrize("mode", ["corrected", "none"])
@pytest.mark.parametrize("law", ["smooth", "linear"])
@pytest.mark.parametrize("speed, max_velocity, limiting", [
    (60.0, {}, None),                              # the recipe's joint speed limits every joint
    (120.0, {"j4": 40.0}, 3),                      # the j4 drive's max_velocity limits
    (120.0, {"j1": 5.0}, 0)])
def test_segment_count_keeps_every_joint_within_its_speed(mode, law, speed, max_velocity, limiting):
    st = Stations(max_velocity=max_velocity)
    segs, rep = Mover(ROBOT, st).plan(Q0, Q1, MotionSpec(mode, T, law, speed))
    vmax = np.minimum(speed, 0.99 * np.array([({j: 720.0 for j in JOINT_NAMES} | max_velocity)[j]
                                              for j in JOINT_NAMES]))
    ratio = np.abs(velocities(segs)) / vmax
    assert ratio.max() <= 1.0 + 1e-9                  # never over the limit ...
    # ... nor needlessly slow (in corrected mode the count budgets the slowest station's λ
    # for every joint, so a joint with a shorter λ may stay below its limit by that much)
    floor = 0.9 * ((T - LAM.max()) / (T - LAM.min()) if mode == "corrected" else 1.0)
    assert ratio.max() >= floor
    if limiting is not None:
        assert int(np.argmax(ratio.max(axis=0))) == limiting
    assert rep.segments == len(segs)


def test_a_slower_joint_speed_takes_more_segments():
    fast = Mover(ROBOT, Stations()).plan(Q0, Q1, MotionSpec("none", T, "linear", 120.0))[1]
    slow = Mover(ROBOT, Stations()).plan(Q0, Q1, MotionSpec("none", T, "linear", 30.0))[1]
    assert slow.segments >= 3.9 * fast.segments


# ------------------------------------------------------------------------------ time law, path
def test_smooth_time_law_gives_short_first_and_last_steps():
    segs, rep = Mover(ROBOT, Stations()).plan(Q0, Q1, MotionSpec("none", T, "smooth", 120.0))
    step = np.linalg.norm(np.diff(targets(Q0, segs), axis=0), axis=1)
    assert rep.path == "line"
    assert step[0] < 0.01 * step.max() and step[-1] < 0.01 * step.max()
    assert np.argmax(step) in range(len(step) // 3, 2 * len(step) // 3 + 1)


def test_linear_time_law_in_joint_space_gives_equal_steps():
    q0 = np.array([40.0, -60.0, 0.0, 0.0])            # other elbow: joint-space path
    segs, rep = Mover(ROBOT, Stations()).plan(q0, Q1, MotionSpec("none", T, "linear", 120.0))
    assert rep.path == "joints"
    steps = np.diff(targets(q0, segs), axis=0)
    np.testing.assert_allclose(steps, np.broadcast_to(steps[0], steps.shape), atol=1e-9)


def test_a_reachable_straight_line_is_planned_as_a_line():
    segs, rep = Mover(ROBOT, Stations()).plan(Q0, Q1, MotionSpec("corrected", T, "smooth", 120.0))
    assert rep.path == "line"
    a, b = ROBOT.fk(Q0), ROBOT.fk(Q1)
    u = (b[:3] - a[:3]) / np.linalg.norm(b[:3] - a[:3])
    for s in segs:
        p = ROBOT.fk(s.target_deg)[:3] - a[:3]
        assert np.linalg.norm(p - (p @ u) * u) < 1e-6       # on the straight line
    np.testing.assert_array_equal(segs[-1].target_deg, Q1)


def test_the_other_elbow_falls_back_to_joint_space():
    q0 = np.array([40.0, -60.0, 0.0, 0.0])
    segs, rep = Mover(ROBOT, Stations()).plan(q0, Q1, MotionSpec("corrected", T, "smooth", 120.0))
    assert rep.path == "joints"
    s = TIME_LAWS["smooth"](np.linspace(0.0, 1.0, rep.segments + 1))[1:, None]
    np.testing.assert_allclose(targets(q0, segs)[1:], q0 + s * (Q1 - q0), atol=1e-9)
    np.testing.assert_array_equal(segs[-1].target_deg, Q1)


# ------------------------------------------------------------------------------ refusals
@pytest.mark.parametrize("delta", [0.0, 1e-9])
def test_T_not_above_lambda_raises(delta):
    st = Stations(lam=[0.001, 0.002, 0.003, 0.010])
    with pytest.raises(TrajectoryError, match="not longer than the delay of j4"):
        Mover(ROBOT, st).plan(Q0, Q0 + [delta, 0, 0, 0], MotionSpec("corrected", T, "smooth", 120.0))


def test_T_not_above_lambda_raises_for_a_real_move():
    """Refused at the first plan's first burst: each plan the Mover tries looks at one burst's
    delays, so one look means it never went on to plan ever more segments."""
    st = Stations(lam=[0.001, 0.002, 0.003, 0.012])
    with pytest.raises(TrajectoryError, match="not longer than the delay of j4"):
        Mover(ROBOT, st).plan(Q0, Q1, MotionSpec("corrected", T, "smooth", 120.0))
    assert st.bases == [0x200] and st.corrected == []


def test_sync_and_none_do_not_need_T_above_lambda():
    st = Stations(lam=[0.02] * 4, lam_sync=[0.02] * 4)
    for mode in ("sync", "none"):
        segs, _ = Mover(ROBOT, st).plan(Q0, Q1, MotionSpec(mode, T, "smooth", 120.0))
        assert len(segs) > 1


@pytest.mark.parametrize("spec, words", [
    (MotionSpec("fast", T, "smooth", 60.0), "motion mode 'fast'"),
    (MotionSpec("corrected", T, "cubic", 60.0), "time law 'cubic'")])
def test_bad_spec_raises(spec, words):
    with pytest.raises(TrajectoryError, match=words):
        Mover(ROBOT, Stations()).plan(Q0, Q1, spec)


# ------------------------------------------------------------------------------ check_mode
SYNC_WHY = "the joint stations do not support SYNC (stations[].supports_sync)"


def test_check_mode_reasons():
    assert check_mode("sync", 0.01, False, LAM) == SYNC_WHY
    assert check_mode("sync", 0.001, False, LAM) == SYNC_WHY          # SYNC is named first
    assert check_mode("corrected", 0.004, True, LAM) == (
        "segment time 4.000 ms is not longer than the delay of j4 (λ = 4.000 ms measured on the bus)")
    assert check_mode("sync", 0.0045, True, [0.005, 0.002, 0.003, 0.004]) == (
        "segment time 4.500 ms is not longer than the delay of j1 (λ = 5.000 ms measured on the bus)")
    assert check_mode("corrected", 0.0041, False, LAM) is None        # no SYNC needed
    assert check_mode("sync", 0.0041, True, LAM) is None
    assert check_mode("none", 0.001, False, LAM) is None              # no constraint at all


# ------------------------------------------------------------------------------ motion_check
BRACKET = REPO_RECIPES / "bracket-a.yaml"


def line_of(text: str, start: str) -> int:
    return next(i for i, line in enumerate(text.splitlines(), 1) if line.startswith(start))


def test_motion_check_refuses_sync_on_stations_without_sync():
    text = BRACKET.read_text().replace("  sync: corrected", "  sync: sync", 1)
    recipe = parse_recipe(text, str(BRACKET))
    with pytest.raises(ConfigError) as exc:
        motion_check(False, LAM)(recipe, text, str(BRACKET))
    assert str(exc.value) == (f"{BRACKET}:{line_of(text, '  sync:')}: motion.sync: {SYNC_WHY} "
                              "(motion.sync: sync)")
    motion_check(True, LAM)(recipe, text, str(BRACKET))              # with SYNC: fine


@pytest.mark.parametrize("mode", ["corrected", "sync"])
def test_motion_check_refuses_a_segment_time_not_above_lambda(mode):
    text = BRACKET.read_text().replace("  sync: corrected", f"  sync: {mode}", 1)
    recipe = parse_recipe(text, str(BRACKET))
    lam = [0.001, 0.002, 0.003, 0.010]
    with pytest.raises(ConfigError) as exc:
        motion_check(True, lam)(recipe, text, str(BRACKET))
    assert str(exc.value) == (
        f"{BRACKET}:{line_of(text, '  segment_ms:')}: motion.segment_ms: segment time 10.000 ms is "
        f"not longer than the delay of j4 (λ = 10.000 ms measured on the bus) (motion.sync: {mode})")
    motion_check(True, [0.001, 0.002, 0.003, 0.0099])(recipe, text, str(BRACKET))


def test_motion_check_lets_none_run_whatever_the_delays():
    text = BRACKET.read_text().replace("  sync: corrected", "  sync: none", 1)
    motion_check(False, [0.05] * 4)(parse_recipe(text, str(BRACKET)), text, str(BRACKET))


def test_recipe_store_rejects_what_the_motion_check_refuses(rdir):
    store = RecipeStore(rdir, check=motion_check(False, LAM))
    entries = store.refresh()
    assert {(e.action, e.target.rsplit("/", 1)[-1]) for e in entries} == {
        ("activate", "bracket-a.yaml"), ("reject", "pin-b.yaml")}
    [rej] = [e for e in entries if e.action == "reject"]
    text = (rdir / "pin-b.yaml").read_text()
    assert re.fullmatch(rf"{re.escape(str(rdir / 'pin-b.yaml'))}:{line_of(text, '  sync:')}: "
                        rf"motion\.sync: .*\(motion\.sync: sync\)", rej.result)
    assert set(store.active) == {"bracket-a"}
