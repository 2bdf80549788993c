"""CycleRunner: one part's cycle against fake joint stations and a fake measuring camera.

The fakes stand in for hardware. :class:`FakeStations` has what :class:`cell.motion.mover.Mover`
and :class:`cell.cycle.runner.CellArm` use: ``stream``, ``burst_delays`` (fixed per-joint delays),
``corrected_velocities`` (from those delays), ``wait_reached``, ``actual_positions``,
``cfg.station(j).max_velocity`` and ``quick_stop_all``. A streamed move puts the joints on
its last target at once; each wait takes 50 ms of a :class:`cell.clock.ManualClock`.
:class:`FakeCamera` has the :class:`cell.vision.measure.MeasuringCamera` interface: the part lies
at ``part``, the tool where the fake joints put it (nominal kinematics) plus a constant
``bias`` (the model error the compensation removes). The cycle log is a real
:class:`cell.cyclelog.CycleLog` on a temporary SQLite file; the recipe is the shipped
``recipes/bracket-a.yaml``.
"""
import sqlite3
from types import SimpleNamespace

import numpy as np
import pytest

from cell.clock import ManualClock
from cell.cycle.runner import (VERIFY_NOTE, CancelToken, CycleCancelled, CycleRunner, CycleSettings,
                        OffsetMemory)
from cell.cycle.statemachine import State
from cell.cyclelog import CycleLog
from cell.faults import CellFault, Fault
from cell.kinematics import Scara
from cell.recipes import ActiveRecipe, content_hash, parse_recipe
from cell.vision import VisionError
from cell.vision.measure import VISION_FAULTS, MeasuringCamera
from drivers.stations.faults import FaultCode, FaultRecord, StationFaultError
from drivers.stations.streaming import StationCommandError

from tests.cell.conftest import REPO_RECIPES

ROBOT = Scara.preset("seed000")
START = (40.0, 60.0, 0.0, 0.0)                         #: joints at power-up
LAM = (0.001, 0.002, 0.003, 0.004)                     #: λ of a reception burst (base 0x200), s
LAM_SYNC = (0.0005, 0.001, 0.0015, 0.002)              #: λ of a SYNC write-ahead burst (0x400), s
PART = (250.3, 929.8)                                  #: where the camera sees the part, mm
T_WAIT = 0.05                                          #: clock time one wait_reached takes, s
STEPS = ["approach", "capture", "locate", "compensate", "final_move", "verify"]


class FakeStations:
    def __init__(self, clock, lam=LAM, lam_sync=LAM_SYNC, max_velocity=720.0, start=START):
        self.clock = clock
        self.lam, self.lam_sync = np.array(lam), np.array(lam_sync)
        self.cfg = SimpleNamespace(station=lambda joint: SimpleNamespace(max_velocity=max_velocity))
        self.pos = np.array(start, dtype=float)
        self.streams: list[tuple[str, list, np.ndarray]] = []   #: (mode, segments, start joints)
        self.waits: list[tuple[float, float]] = []
        self.quick_stops: list[str] = []
        self.progress: list[State] = []      #: runner.progress at every call (runner set later)
        self.runner = None
        self.on_stream = None                #: hook(n) before the n-th stream (1-based)
        self.on_wait = None                  #: hook(n) at the n-th wait
        self.on_actual = None

    def _seen(self):
        if self.runner is not None:
            self.progress.append(self.runner.progress)

    def stream(self, segments, mode="reception", lead_s=None):
        self._seen()
        segments = list(segments)
        if self.on_stream:
            self.on_stream(len(self.streams) + 1)
        self.streams.append((mode, segments, self.pos.copy()))
        self.pos = np.array(segments[-1].target_deg, dtype=float)

    def burst_delays(self, targets_deg, velocities_deg_s, base=0x200):
        assert base in (0x200, 0x400)
        return (self.lam_sync if base == 0x400 else self.lam).copy()

    def corrected_velocities(self, targets_deg, deltas_deg, segment_s, hint_s=None):
        """Seed 002's ωᵢ = Δθᵢ / (T − λᵢ) for a reception burst (the λ above)."""
        lam = self.burst_delays(targets_deg, np.abs(deltas_deg) / segment_s)
        if segment_s <= float(np.max(lam)):
            raise StationCommandError(f"segment time {segment_s} s is not longer than λ")
        return np.asarray(deltas_deg, dtype=float) / (segment_s - lam), lam

    def wait_reached(self, timeout_s, tol=0.02):
        self.waits.append((timeout_s, tol))
        if self.on_wait:
            self.on_wait(len(self.waits))
        self.clock.advance(T_WAIT)

    def actual_positions(self):
        if self.on_actual:
            self.on_actual()
        return self.pos.copy()

    def quick_stop_all(self, reason="requested"):
        self.quick_stops.append(reason)


class FakeCamera:
    """MeasuringCamera interface (grab, find, tool) over the fake joints."""

    def __init__(self, stations: FakeStations, part=PART, bias=(0.3, -0.2), place_shift=(0.0, 0.0)):
        self.st = stations
        self.part = np.array(part, dtype=float)
        self.bias = np.array(bias)
        self.place_shift = np.array(place_shift)      #: tool offset once lowered to the place z
        self.calls: list[str] = []
        self.nears: list = []                         #: (where the cycle said to look, joints)
        self.on_tool = None                           #: hook() at every tool measurement

    def grab(self, cancel=None):
        self.st._seen()
        self.calls.append("grab")
        return np.zeros((8, 8), np.uint8)

    def find(self, image, radius_mm, what, near_mm=None, within_mm=None):
        self.st._seen()
        self.calls.append(f"find {what} r={radius_mm}")
        return self.part.copy()

    def tool(self, cancel=None, near_mm=None):
        self.st._seen()
        self.calls.append("tool")
        self.nears.append((np.array(near_mm), self.st.pos[:2].copy()))
        if self.on_tool:
            self.on_tool()
        q = self.st.pos
        shift = self.place_shift if q[2] <= -40.0 else 0.0
        return ROBOT.fk_planar(q[0], q[1]) + self.bias + shift


class SpyLog(CycleLog):
    """The real log; remembers the runner's step while the row is written, and lets the
    write take ``write_s`` of the manual clock."""

    runner = None
    clock = None
    write_s = 0.0
    progress_at_write = None

    def add_cycle(self, rec):
        self.progress_at_write = self.runner.progress if self.runner else None
        if self.clock is not None:
            self.clock.advance(self.write_s)
        return super().add_cycle(rec)


class BrokenLog(CycleLog):
    def add_cycle(self, rec):
        raise sqlite3.OperationalError("disk I/O error")


def active(mode: str | None = None, edits=()) -> ActiveRecipe:
    """bracket-a as shipped, in sync ``mode``, with ``edits`` (old, new) made to its text."""
    path = REPO_RECIPES / "bracket-a.yaml"
    text = path.read_text(encoding="utf-8")
    if mode is not None:
        edits = [("  sync: corrected", f"  sync: {mode}"), *edits]
    for old, new in edits:
        assert old in text
        text = text.replace(old, new, 1)
    return ActiveRecipe(parse_recipe(text, str(path)), content_hash(text), text, str(path))


class Rig:
    def __init__(self, tmp_path, log_cls=SpyLog, camera=None, **stations):
        self.clock = ManualClock(1000.0)
        self.st = FakeStations(self.clock, **stations)
        self.cam = camera if camera is not None else FakeCamera(self.st)
        self.log = log_cls(tmp_path / "cycles.db")
        self.memory = OffsetMemory()
        self.runner = CycleRunner(ROBOT, self.st, self.cam, self.log, CycleSettings(), self.memory,
                                  self.clock)
        self.st.runner = self.runner
        self.log.runner, self.log.clock = self.runner, self.clock
        self.token = CancelToken(self.clock)

    def run(self, recipe=None, part_id=42):
        return self.runner.run(recipe or active(), part_id, self.token)

    def rows(self):
        return self.log.cycles()


@pytest.fixture
def rig(tmp_path):
    r = Rig(tmp_path)
    yield r
    r.log.close()


def seg_deltas(start, segments) -> np.ndarray:
    targets = np.array([start] + [s.target_deg for s in segments])
    return np.diff(targets, axis=0)


# ------------------------------------------------------------------------------ done
@pytest.mark.parametrize("mode, stream_mode, lam", [
    ("corrected", "reception", LAM), ("sync", "sync", LAM_SYNC), ("none", "reception", LAM)])
def test_done_cycle_streams_every_move_in_the_recipes_mode_and_logs_one_row(tmp_path, mode,
                                                                             stream_mode, lam):
    rig = Rig(tmp_path)
    rig.log.write_s = 0.125
    recipe = active(mode)
    out = rig.run(recipe, part_id=42)
    assert (out.status, out.fault_code, out.fault_text) == ("done", 0, "")
    assert rig.st.streams and {m for m, _, _ in rig.st.streams} == {stream_mode}
    T = recipe.recipe.motion.segment_ms / 1000.0
    for _, segs, start in rig.st.streams:           # seed 002 velocities of the mode
        want = seg_deltas(start, segs) / ((T - np.array(lam)) if mode == "corrected" else T)
        np.testing.assert_allclose([s.velocity_deg_s for s in segs], want, rtol=1e-12, atol=1e-12)
    assert rig.st.waits == [(10.0, 0.001)] * len(rig.st.streams)   # CycleSettings' time-out, tol
    [row] = rig.rows()
    assert row.id == out.record.id
    assert (row.status, row.part_id, row.recipe, row.recipe_hash, row.method) == (
        "done", 42, "bracket-a", recipe.hash, "lattice")
    assert (row.fault_code, row.fault_text) == (0, "")
    assert row.motion == {"mode": mode, "moves": len(rig.st.streams),
                          "segments": sum(len(s) for _, s, _ in rig.st.streams),
                          "segment_ms": 10.0, "time_law": "smooth", "paths": ["line"],
                          "delays_ms": [pytest.approx(v * 1e3) for v in lam]}
    assert list(row.step_times) == STEPS
    assert row.target_mm == pytest.approx(PART)
    assert row.moves == out.record.moves >= 2          # first arrival + a correction
    vias = sum(1 for step in row.trace if "via_units" in step)
    assert vias >= 1                                 # the approach pose lies on the wrong side
    assert len(rig.st.streams) == row.moves + vias + 2   # approach + arrivals + final move
    assert row.verify_error_mm <= recipe.recipe.verify.tolerance_mm
    assert row.initial_error_mm > row.final_error_mm
    assert row.cycle_time_s == pytest.approx(T_WAIT * len(rig.st.streams))   # up to the write
    assert out.log_write_s == 0.125                   # the write's own time, for the PLC
    assert len(row.trace) == len(out.record.trace) >= 1
    assert len(rig.memory.history["bracket-a"]) == 1  # learned from a completed cycle
    # every tool measurement looks where the model puts the tool at the joints it went to
    assert rig.cam.nears and all(np.allclose(near, ROBOT.fk_planar(*q)) for near, q in rig.cam.nears)
    rig.log.close()


def test_final_move_goes_down_to_the_place_height(rig):
    out = rig.run()
    assert out.status == "done"
    approach_z = active().recipe.approach.z_mm
    place_z = active().recipe.place.z_mm
    assert rig.st.streams[0][1][-1].target_deg[2] == pytest.approx(approach_z)
    assert all(s[1][-1].target_deg[2] == pytest.approx(approach_z) for s in rig.st.streams[1:-1])
    assert rig.st.streams[-1][1][-1].target_deg[2] == pytest.approx(place_z)


def test_progress_goes_through_the_steps_in_order(rig):
    assert rig.runner.progress is State.IDLE
    out = rig.run()
    assert out.status == "done"
    seen = [p for i, p in enumerate(rig.st.progress) if i == 0 or p is not rig.st.progress[i - 1]]
    assert seen == [State.APPROACH, State.CAPTURE, State.LOCATE, State.COMPENSATE,
                    State.FINAL_MOVE, State.VERIFY]
    assert rig.log.progress_at_write is State.LOGGING   # the row is written in LOGGING
    assert rig.runner.progress is State.LOGGING
    assert rig.cam.calls[:2] == ["grab", "find part fiducial r=1.5"]


def test_a_new_cycle_does_not_start_at_the_last_cycles_step(rig):
    assert rig.run().status == "done"
    at_start = []
    rig.st.on_actual = lambda: at_start.append(rig.runner.progress)
    rig.token = CancelToken(rig.clock)
    assert rig.run(part_id=43).status == "done"
    assert at_start[0] in (State.IDLE, State.APPROACH)


def test_a_second_cycle_starts_from_the_learned_offset(rig):
    first = rig.run()
    rig.token = CancelToken(rig.clock)
    second = rig.run(part_id=43)
    assert (first.status, second.status) == ("done", "done")
    # the memory holds where the first cycle ended: the second arrives there at once
    assert second.record.trace[0]["joints_deg"] == first.record.trace[-1]["joints_deg"]
    assert second.record.moves <= first.record.moves
    assert [r.part_id for r in rig.rows()] == [42, 43]


# ------------------------------------------------------------------------------ cancel
@pytest.mark.parametrize("code, text", [(0, "abort by PLC"), (101, "PLC heartbeat lost")])
def test_cancel_before_start_records_an_aborted_cycle_with_the_tokens_reason(rig, code, text):
    rig.token.cancel(code, text)
    out = rig.run()
    assert (out.status, out.fault_code, out.fault_text) == ("aborted", code, text)
    assert rig.st.streams == [] and rig.cam.calls == []
    [row] = rig.rows()
    assert (row.status, row.fault_code, row.fault_text) == ("aborted", code, text)
    assert row.motion == {"mode": "corrected", "moves": 0}
    assert row.step_times == {} and row.target_mm is None
    assert rig.memory.history == {}


def test_cancel_mid_cycle_stops_after_the_move_with_the_tokens_reason(rig):
    def on_wait(n):
        if n == 2:                                    # during the first compensation move
            rig.token.cancel(101, "PLC heartbeat lost for more than 1.0 s")
    rig.st.on_wait = on_wait
    out = rig.run()
    assert (out.status, out.fault_code, out.fault_text) == (
        "aborted", 101, "PLC heartbeat lost for more than 1.0 s")
    assert len(rig.st.streams) == 2                   # nothing moved or measured after the cut
    assert rig.cam.calls == ["grab", "find part fiducial r=1.5"]
    [row] = rig.rows()
    assert (row.status, row.fault_code) == ("aborted", 101)
    assert list(row.step_times) == ["approach", "capture", "locate"]
    assert row.motion["moves"] == 2
    assert rig.runner.progress is State.COMPENSATE
    assert rig.memory.history == {}


def test_a_quick_stop_after_the_cancel_keeps_the_tokens_reason(rig):
    """The scan loop cancels (abort) and quick-stops: the move then fails with the stations'
    QUICK_STOP fault; the cycle reports the abort, not the station fault."""
    def on_wait(n):
        if n == 3:
            rig.token.cancel(0, "abort by PLC")
            raise StationFaultError(FaultRecord(FaultCode.QUICK_STOP, "quick stop"), "wait_reached")
    rig.st.on_wait = on_wait
    out = rig.run()
    assert (out.status, out.fault_code, out.fault_text) == ("aborted", 0, "abort by PLC")
    [row] = rig.rows()
    assert (row.status, row.fault_code, row.fault_text) == ("aborted", 0, "abort by PLC")


def test_a_cancel_after_the_last_step_keeps_the_cycle_done(rig):
    def on_tool():
        if rig.runner.progress is State.VERIFY:
            rig.token.cancel(0, "abort by PLC")       # too late: nothing is checked after verify
    rig.cam.on_tool = on_tool
    out = rig.run()
    assert rig.token.cancelled                        # the cancel did come, during verify
    assert out.status == "done" and out.fault_code == 0
    assert rig.rows()[0].status == "done"


# ------------------------------------------------------------------------------ failures
def test_motion_timeout_is_fault_403(rig):
    def on_wait(n):
        raise TimeoutError("targets not reached within 10.00 s: j1 at 40.0000 for 58.1000")
    rig.st.on_wait = on_wait
    out = rig.run()
    assert (out.status, out.fault_code) == ("aborted", Fault.MOTION_TIMEOUT)
    assert out.fault_text == "targets not reached within 10.00 s: j1 at 40.0000 for 58.1000"
    [row] = rig.rows()
    assert (row.status, row.fault_code, row.fault_text) == ("aborted", 403, out.fault_text)
    assert row.step_times == {} and row.motion["moves"] == 0
    assert rig.cam.calls == []


def test_motion_timeout_in_the_final_move_is_403(rig):
    def on_wait(n):
        if rig.runner.progress is State.FINAL_MOVE:
            raise TimeoutError("targets not reached within 10.00 s: j3")
    rig.st.on_wait = on_wait
    out = rig.run()
    assert (out.status, out.fault_code) == ("aborted", 403)
    [row] = rig.rows()
    assert list(row.step_times) == STEPS[:4] and row.fault_code == 403


class FailingDriver:
    def grab(self):
        raise OSError("device /dev/video0 gone")


def test_camera_grab_failure_is_fault_301(tmp_path):
    rig = Rig(tmp_path, camera=MeasuringCamera(FailingDriver(), calibration=None, tool_radius_mm=2.0))
    out = rig.run()
    assert (out.status, out.fault_code) == ("aborted", Fault.CAMERA_FAILED)
    assert out.fault_text == "camera grab failed: device /dev/video0 gone"
    [row] = rig.rows()
    assert (row.fault_code, list(row.step_times)) == (301, ["approach"])
    assert rig.cam.last_error == "device /dev/video0 gone"
    rig.log.close()


@pytest.mark.parametrize("kind, code", sorted(VISION_FAULTS.items()))
def test_vision_failures_map_to_their_fault_codes(tmp_path, kind, code):
    class Driver:
        def grab(self):
            return SimpleNamespace(image=np.zeros((48, 64), np.uint8))

    searches = []

    def locate(image, cal, **find_kwargs):
        searches.append(find_kwargs)
        raise VisionError(f"{kind} at (10, 12) px", kind)
    # 0.1 mm per px, the part's nominal place (250, 930) mm at the frame's centre
    cal = SimpleNamespace(width=640, height=480, mm_per_px=lambda x, y: 0.1,
                          base_to_pixel=lambda x, y: (319.5 + (x - 250.0) / 0.1, 239.5 - (y - 930.0) / 0.1))
    camera = MeasuringCamera(Driver(), cal, tool_radius_mm=2.0, locate=locate)
    rig = Rig(tmp_path, camera=camera)
    out = rig.run()
    assert (out.status, out.fault_code) == ("aborted", code)
    assert out.fault_text == f"part fiducial: {kind} at (10, 12) px"
    assert rig.rows()[0].fault_code == code
    assert list(rig.rows()[0].step_times) == ["approach", "capture"]
    r_px = active().recipe.part.fiducial_radius_mm / 0.1                # the part's size
    size = dict(expected=1, min_radius_px=pytest.approx(r_px * 0.7), max_radius_px=pytest.approx(r_px * 1.3))
    # first the window: search radius 3 + 1 mm, radius 1.5 × 1.3, 0.5 mm: 6.45 mm = 64.5 px
    assert searches == [dict(size, roi=(255, 175, 384, 304)), dict(size, roi=None)]
    assert camera.window_misses == 1
    rig.log.close()


def test_vision_fault_codes():
    assert VISION_FAULTS == {"no_target": 302, "multiple": 303, "cut": 304, "saturated": 305,
                             "low_contrast": 306, "bad_image": 301, "other": 307}


def test_camera_fault_from_the_measuring_camera_keeps_its_code(rig):
    def on_tool():
        raise CellFault(Fault.TARGET_CUT, "tool fiducial: touches the image edge")
    rig.cam.on_tool = on_tool
    out = rig.run()
    assert (out.status, out.fault_code, out.fault_text) == (
        "aborted", 304, "tool fiducial: touches the image edge")


def test_part_outside_the_search_window_is_fault_308(rig):
    rig.cam.part = np.array([250.0 + 3.5, 930.0])
    out = rig.run()
    assert (out.status, out.fault_code) == ("aborted", Fault.PART_OUT_OF_WINDOW)
    assert "3.500 mm from nominal > search radius 3.0 mm" in out.fault_text
    assert rig.st.streams and len(rig.st.streams) == 1     # the approach only


def test_a_part_placed_off_tolerance_is_finished_by_an_extra_move(rig):
    """The tool lands 0.25 mm off once lowered: the cycle lifts it, moves to the command the
    placed measurement predicts nearest, places and verifies again, and the part is done."""
    rig.cam.place_shift = np.array([0.25, 0.0])
    out = rig.run()
    assert (out.status, out.fault_code) == ("done", 0)
    [row] = rig.rows()
    assert row.verify_error_mm <= 0.08
    last = row.trace[-1]
    assert last["note"].startswith(VERIFY_NOTE) and last["error_mm"] == pytest.approx(row.verify_error_mm)
    assert row.moves == sum(1 for step in row.trace if step["moved"])
    zs = [start[2] for _, _, start in rig.st.streams] + [rig.st.pos[2]]
    approach_z, place_z = active().recipe.approach.z_mm, active().recipe.place.z_mm
    # placed, lifted, (via point,) moved, lowered
    tail = [place_z] + [approach_z] * (3 if "via_units" in last else 2) + [place_z]
    assert zs[-len(tail):] == pytest.approx(tail)
    assert len(rig.memory.history["bracket-a"]) == 1


def test_verify_out_of_tolerance_with_no_extra_move_left_is_status_fault_402(rig):
    rig.cam.place_shift = np.array([0.25, 0.0])
    out = rig.run(active(edits=[("  max_moves: 4", "  max_moves: 4\n  extra_moves: 0")]))
    assert (out.status, out.fault_code) == ("fault", Fault.VERIFY_OUT_OF_TOLERANCE)
    assert out.fault_text.startswith("verified error 0.2")
    assert "mm > tolerance 0.08 mm; compensation.extra_moves = 0 spent" in out.fault_text
    [row] = rig.rows()
    assert (row.status, row.fault_code) == ("fault", 402)
    assert row.verify_error_mm == pytest.approx(0.25, abs=0.06)
    assert list(row.step_times) == STEPS[:5]           # verify did not finish
    assert rig.memory.history == {}                   # nothing learned from a failed part


def test_extra_moves_stop_at_the_recipes_limit(rig):
    """Every placement lands further off (a drifting fixture, say): after its one extra
    move the cycle faults and says the moves are spent."""
    calls = []

    def drift():
        calls.append(1)
        rig.cam.place_shift = np.array([0.2 * len(calls), 0.0])
    rig.cam.on_tool = drift
    out = rig.run(active(edits=[("  max_moves: 4", "  max_moves: 4\n  extra_moves: 1")]))
    assert (out.status, out.fault_code) == ("fault", Fault.VERIFY_OUT_OF_TOLERANCE)
    assert "compensation.extra_moves = 1 spent (the next move was predicted to" in out.fault_text
    [row] = rig.rows()
    assert sum(1 for step in row.trace if step["note"].startswith(VERIFY_NOTE)) == 1


def test_verify_fault_says_when_no_command_can_reach_the_tolerance(rig):
    """A tolerance finer than the command lattice: no whole-unit command is predicted within
    it, so the cycle faults at once instead of moving."""
    rig.cam.place_shift = np.array([0.25, 0.0])
    out = rig.run(active(edits=[("  tolerance_mm: 0.08", "  tolerance_mm: 0.003")]))
    assert (out.status, out.fault_code) == ("fault", Fault.VERIFY_OUT_OF_TOLERANCE)
    assert "no whole-unit command is predicted within it (nearest " in out.fault_text
    [row] = rig.rows()
    assert not any(step["note"].startswith(VERIFY_NOTE) for step in row.trace)


def test_station_fault_error_is_200_plus_its_code(rig):
    err = StationFaultError(FaultRecord(FaultCode.EMCY_LIMIT, "set-point beyond limits", "j2", 2),
                            "stream")

    def on_stream(n):
        if n == 2:
            raise err
    rig.st.on_stream = on_stream
    out = rig.run()
    assert (out.status, out.fault_code, out.fault_text) == ("aborted", 204, str(err))
    [row] = rig.rows()
    assert (row.status, row.fault_code) == ("aborted", 204)


def test_unexpected_error_is_internal_501(rig):
    def on_stream(n):
        raise ZeroDivisionError("oops")
    rig.st.on_stream = on_stream
    out = rig.run()
    assert (out.status, out.fault_code) == ("aborted", Fault.INTERNAL)
    assert "ZeroDivisionError" in out.fault_text


def test_unreachable_part_is_401(rig):
    """A part found beyond the arm's reach (l1 + l2 = 1000 mm): no IK, fault 401."""
    a = active()
    text = (a.text.replace("nominal_xy_mm: [250.0, 930.0]", "nominal_xy_mm: [0.0, 998.0]")
            .replace("search_radius_mm: 3.0", "search_radius_mm: 5.0"))
    rig.cam.part = np.array([0.0, 1002.0])
    out = rig.runner.run(ActiveRecipe(parse_recipe(text, a.path), "h", text, a.path), 1, rig.token)
    assert (out.status, out.fault_code) == ("aborted", Fault.UNREACHABLE)
    assert "out of reach" in out.fault_text
    assert list(rig.rows()[0].step_times) == ["approach", "capture", "locate"]


def test_log_write_failure_on_a_done_cycle_is_fault_502(tmp_path):
    rig = Rig(tmp_path, log_cls=BrokenLog)
    out = rig.run()
    assert (out.status, out.fault_code) == ("fault", Fault.LOG_WRITE_FAILED)
    assert out.fault_text == "cycle log write failed: disk I/O error"
    assert out.record.id is None
    rig.log.close()


def test_log_write_failure_keeps_an_aborted_cycles_own_reason(tmp_path):
    rig = Rig(tmp_path, log_cls=BrokenLog)
    rig.token.cancel(0, "abort by PLC")
    out = rig.run()
    assert (out.status, out.fault_code, out.fault_text) == ("aborted", 0, "abort by PLC")
    rig.log.close()


def test_run_safely_without_a_recipe_is_aborted_with_the_tokens_reason(rig):
    rig.token.cancel(0, "recipe 3 vanished")
    out = rig.runner.run_safely(None, 1, rig.token)
    assert (out.status, out.fault_code, out.fault_text) == ("aborted", 0, "recipe 3 vanished")
    assert rig.runner.outcome is out and rig.rows() == []
    rig.token = CancelToken(rig.clock)
    out = rig.runner.run_safely(active(), 2, rig.token)
    assert out.status == "done" and rig.runner.outcome is out


def test_cancel_token_keeps_the_first_reason():
    t = CancelToken(ManualClock())
    assert not t.cancelled
    t.check()
    t.cancel(101, "first")
    t.cancel(0, "second")
    assert t.cancelled and (t.code, t.text) == (101, "first")
    with pytest.raises(CycleCancelled):
        t.check()
