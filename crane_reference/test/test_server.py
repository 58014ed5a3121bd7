"""The reference server (:mod:`crane_reference.stream.server`) and its solver clients without ROS: a
clock of plain integers drives it; what it serves is compared with an independent
:class:`ReferenceStream` sampled at the same stream times."""

from __future__ import annotations

import dataclasses
import math
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from crane_reference.base.health import Health, Level, startup_health
from crane_reference.model.config import load_config
from crane_reference.model.parameters import Task
from crane_reference.motion.programmed_motion import ConstraintSingularityError
from crane_reference.motion.simulation import MotionStepper
from crane_reference.ros.service_replies import pause_reply
from crane_reference.stream import solver as solver_module
from crane_reference.stream.ahead import COMPUTE_SLICE, URGENT_REFILL
from crane_reference.stream.frames import FrameRequest
from crane_reference.stream.health import serving_health
from crane_reference.stream.reference_stream import ERROR, PAUSED, RUNNING, ReferenceStream
from crane_reference.stream.schedule import URGENT_PART, FrameSchedule
from crane_reference.stream.served import CommandRefusedError, Preview, ServerStatus
from crane_reference.stream.server import ReferenceServer
from crane_reference.stream.solver import LocalSolver, SolverProcess
from crane_reference.stream.solver_messages import StreamSpec, StreamStatus
from crane_reference.stream.stream_solver import StreamSolver
from crane_reference.stream.targets import UnreachableTargetError

RATE = 100  # [Hz]
LEAD = 0.1  # [s]
NS = 10**9
PERIOD = NS // RATE
STEP = 1e-3  # [s]: the integrator step of the served stream and of the streams it is compared with


def spec(**changes) -> StreamSpec:
    config = load_config()
    return StreamSpec(**{"config": config, "model": "rigid", "step": STEP, "blend_time": 0.5, "targets": config.task,
                         "warm_up": False, "ramp_time": 0.3, **changes})


def sample(outgoing):
    """The sample an outgoing row carries."""
    return outgoing.frames.samples.row(outgoing.row)


def wait_ready(server: ReferenceServer, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not server.ready():
        assert time.monotonic() < deadline, "the server made no look-ahead of frames"
        time.sleep(0.01)


@pytest.fixture
def server() -> Iterator[ReferenceServer]:
    served = ReferenceServer(LocalSolver(spec()), RATE, LEAD, Preview(0.2, 4, 10))
    try:
        wait_ready(served)
        yield served
    finally:
        served.close()


def publish(server: ReferenceServer, start_ns: int, seconds: float) -> list:
    """Everything due from start_ns over ``seconds`` on a clock stepped by one period, each step once the
    frame of the next sample is made (as a publisher on a machine fast enough for the solver sees it)."""
    out = []
    for i in range(round(seconds * RATE)):
        deadline = time.monotonic() + 30.0
        while server.schedule.made_k <= server.schedule.next_k:
            assert time.monotonic() < deadline, "no frame for the next sample"
            time.sleep(0.001)
        out += server.due(lambda now_ns=start_ns + i * PERIOD: now_ns).outgoing
    return out


def test_served_samples_are_the_stream_at_consecutive_stamps(server: ReferenceServer) -> None:
    start = 5 * NS
    server.begin(start)
    out = publish(server, start, 1.5)
    assert [o.k for o in out] == list(range(len(out))) and len(out) == 150
    assert [o.stamp_ns for o in out] == [start + k * PERIOD for k in range(150)]
    truth = ReferenceStream(load_config(), "rigid", STEP, blend_time=0.5, ramp_time=0.3)
    truth.compute(1.5)
    np.testing.assert_array_equal([sample(o).q for o in out], [truth.sample(k / RATE).q for k in range(150)])
    previews = [o.k for o in out if o.row in o.frames.previews]  # the look-ahead made before publishing has all;
    assert previews[:10] == list(range(0, 100, 10))  # urgent frames later (this publisher drains the buffer)
    assert all(k % 10 == 0 for k in previews)  # may pass theirs, the cadence stays
    status = server.status(start + 150 * PERIOD)
    assert status.counters["held_late"] == 0 and status.achieved_rate == pytest.approx(RATE, rel=0.02)
    assert server.due(lambda: start + 150 * PERIOD - 1).next_stamp_ns == start + 150 * PERIOD


def test_a_clock_reset_seen_before_it_is_reported_restarts_the_stamps_announced(server: ReferenceServer) -> None:
    """ROS time goes back 120 s (a looped bag).  The publisher reads the new time before rclpy's jump callback
    reports it (nothing is due: the clock is behind); once reported, the status announces the restart (not a
    clock still behind), and publishing goes on sample by sample from the new time, counted as one reset and no
    leap."""
    start = 200 * NS
    server.begin(start)
    before = publish(server, start, 0.5)
    back = start + len(before) * PERIOD - 120 * NS
    assert server.due(lambda: back).outgoing == []
    assert server.status(back).clock_behind == pytest.approx(120.0, abs=0.02)
    server.clock_went_back(back)
    health = serving_health(server.status(back), 0)
    assert health.level == Level.WARN and "the stamps restart" in health.message, health.message
    after = publish(server, back, 0.3)
    assert [o.k for o in after] == list(range(len(before), len(before) + 30))
    assert [o.stamp_ns for o in after] == [back + i * PERIOD for i in range(30)]
    truth = ReferenceStream(load_config(), "rigid", STEP, blend_time=0.5, ramp_time=0.3)
    truth.compute(0.8)
    np.testing.assert_array_equal([sample(o).q for o in after], [truth.sample(o.k / RATE).q for o in after])
    counters = server.status(back + 30 * PERIOD).counters
    assert counters["clock_resets"] == 1 and counters["stamp_leaps"] == 0


def test_a_clock_reset_reported_while_the_clock_is_read_waits_for_that_reading(server: ReferenceServer) -> None:
    """The publisher's clock is read under the server's lock: ROS time goes back 120 s while the publisher reads
    it (the reading from before the jump), and the report of the jump waits until that reading's samples are taken,
    so the reading is not applied after the restart (where it would be a leap forward of the whole jump): one reset,
    no leap, and publishing goes on sample by sample from the new time."""
    start = 200 * NS
    server.begin(start)
    before = publish(server, start, 0.3)
    now = start + len(before) * PERIOD
    back = now - 120 * NS
    report = threading.Thread(target=server.clock_went_back, args=(back,))

    def read_clock() -> int:
        report.start()  # rclpy's jump callback, on the executor's thread
        report.join(0.05)
        return now

    assert [o.k for o in server.due(read_clock).outgoing] == [len(before)]
    report.join(10.0)
    counters = server.status(back).counters
    assert counters["clock_resets"] == 1 and counters["stamp_leaps"] == 0
    after = publish(server, back, 0.2)
    assert [o.k for o in after] == list(range(len(before) + 1, len(before) + 21))
    assert [o.stamp_ns for o in after] == [back + i * PERIOD for i in range(20)]


def test_a_command_takes_effect_at_the_last_sample_within_the_lead(server: ReferenceServer) -> None:
    start = NS
    server.begin(start)
    before = publish(server, start, 0.5)
    targets = Task(3.2, 2.0, 0.2, 5.0)
    server.check_targets(targets)
    k = server.retarget(targets, 0.5, accepted_ns=start + 49 * PERIOD + 1).k  # just after sample 49 went out
    assert k == 49 + round(LEAD * RATE)  # stamped LEAD - 1 ns after the acceptance
    assert server.commands["retarget_stamp_s"] == f"{(start + k * PERIOD) / NS:.6f}"
    after = publish(server, start + len(before) * PERIOD, 1.0)
    truth = ReferenceStream(load_config(), "rigid", STEP, blend_time=0.5, ramp_time=0.3)
    truth.retarget(k / RATE, targets)
    truth.compute(1.5)
    np.testing.assert_array_equal([sample(o).q for o in before + after],
                                  [truth.sample(i / RATE).q for i in range(len(before + after))])
    assert server.stream.targets == targets


class Simulation:
    """A server without its worker thread, run on a simulated clock [ns] that moves only when told (no wall
    clock): the worker's requests (:meth:`ReferenceServer.compute_ahead`) in turn, each answered ``latency(request)``
    seconds after it is asked, while publishing goes on (every sample due is taken, a period at a time); when the
    worker has nothing to do, a period passes."""

    def __init__(self, latency: Callable[[FrameRequest], float]) -> None:
        self.now = NS
        self.server = ReferenceServer(LocalSolver(spec()), RATE, LEAD, Preview(0.2, 4, 10), clock=lambda: self.now,
                                      worker=False)
        self.requests: list[FrameRequest] = []
        self.out: list = []
        ask = self.server.solver.frames

        def frames(request: FrameRequest, keep: float):
            batch = ask(request, keep)
            self.requests.append(request)
            self.publish_until(self.now + round(latency(request) * NS))
            return batch

        self.server.solver.frames = frames
        while self.server.compute_ahead():  # the look-ahead before publishing
            pass
        self.server.begin(self.now)

    def publish_until(self, end_ns: int) -> None:
        """Publish what is due, a period at a time, until the clock reads ``end_ns``."""
        while self.now < end_ns:
            self.now = min(self.now + PERIOD, end_ns)
            self.out += self.server.due(lambda: self.now).outgoing

    def run_until(self, seconds: float) -> None:
        """Serve until ``seconds`` after publishing began."""
        end_ns = NS + round(seconds * NS)
        while self.now < end_ns:
            if not self.server.compute_ahead():
                self.publish_until(self.now + PERIOD)

    def held(self) -> int:
        return self.server.status(self.now).counters["held_late"]


def test_after_a_command_the_urgent_frames_come_in_growing_requests_then_a_full_one() -> None:
    """After a pause (the motion it publishes is computed already, so making frames is all a request does) the
    worker asks for the frames close to publishing in short requests, the first for about the command's lead of
    frames (not the whole urgent quarter of the look-ahead at once, which takes longer to make than a command's
    lead), each for about as many as are ready, so that it leaves the urgent window after a few (the frames ready
    double a request): then a full refill, not a request for each frame or two published meanwhile.  A request
    takes 2 ms and 0.2 ms a frame (simulated); no sample is held."""
    simulation = Simulation(lambda request: 2e-3 + 2e-4 * request.count)
    server = simulation.server
    simulation.run_until(0.5)
    simulation.requests.clear()
    server.command("pause", accepted_ns=simulation.now)
    simulation.run_until(2.0)
    requests = simulation.requests
    most, window = round(URGENT_REFILL * RATE), server.schedule.lookahead // URGENT_PART
    urgent = [r.compute_budget < COMPUTE_SLICE for r in requests]
    first_full = urgent.index(False)
    assert first_full >= 1 and all(urgent[:first_full])
    assert requests[0].count <= max(most, round(LEAD * RATE) + 2) and requests[0].compute_budget <= LEAD
    assert first_full <= math.ceil(math.log2(window / most)) + 3
    assert requests[first_full].count > most
    assert simulation.held() == 0
    assert [o.k for o in simulation.out] == list(range(len(simulation.out)))  # every sample once, in order


def test_a_solver_whose_answers_come_late_gets_ahead_again_after_a_command() -> None:
    """Every answer of the solver comes 150 ms late (simulated: the round trip and a busy machine's scheduling),
    longer than the frames ready after a command last (the lead, 0.1 s): after a pause and a resume the worker
    asks for more frames than are published while it waits, so the frames ready grow back past the urgent window
    and publishing holds no more samples once they have."""
    simulation = Simulation(lambda request: 0.15)
    server = simulation.server
    simulation.run_until(0.3)
    server.command("pause", accepted_ns=simulation.now)
    server.command("resume", accepted_ns=simulation.now)
    simulation.run_until(2.5)
    schedule = server.schedule
    assert schedule.made_k - schedule.next_k >= schedule.lookahead // URGENT_PART
    held = simulation.held()
    assert held > 0  # the late answers held samples after the command
    simulation.run_until(4.0)
    assert simulation.held() == held


def test_restart_only_while_not_publishing_and_its_jump(server: ReferenceServer) -> None:
    server.begin(NS)
    out = publish(server, NS, 1.5)
    with pytest.raises(CommandRefusedError, match="stop publishing"):
        server.restart()
    server.end()
    restart = server.restart()
    assert restart.k == len(out)  # while not publishing: at the next sample, the frames made ahead dropped
    truth = ReferenceStream(load_config(), "rigid", STEP, blend_time=0.5, ramp_time=0.3)
    start = truth.sample(0.0).q  # the static-equilibrium start
    truth.compute(restart.k / RATE)
    jump = np.abs(truth.sample(restart.k / RATE).q - start)
    assert restart.jump == pytest.approx(jump.max(), rel=1e-9)
    assert restart.joint == truth.joint_names[int(jump.argmax())]
    assert "restart_stamp_s" not in server.commands  # not known before publishing begins again
    server.begin(NS + len(out) * PERIOD)
    resumed = publish(server, NS + len(out) * PERIOD, 0.2)
    np.testing.assert_allclose(sample(resumed[0]).q, start, atol=1e-12)
    assert resumed[0].stamp_ns > out[-1].stamp_ns
    assert server.commands["restart_stamp_s"] == f"{resumed[0].stamp_ns / NS:.6f}"  # absolute, as every stamp


def test_a_solver_failure_holds_the_last_sample_and_a_restart_recovers(server: ReferenceServer,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """The integrator fails (injected into MotionStepper.advance_until): the frames made before the failure are
    published, the stream's, then its last sample held (zero velocity) with the stream in ERROR naming the
    failure; a restart while not publishing goes back to the start, RUNNING."""
    truth = ReferenceStream(load_config(), "rigid", STEP, blend_time=0.5, ramp_time=0.3)
    truth.compute(2.5)  # before the failure is injected (into every MotionStepper)
    server.begin(NS)
    before = publish(server, NS, 0.3)

    def fail(self: MotionStepper, t_end: float, stop: np.ndarray | None = None) -> None:
        raise ConstraintSingularityError("injected by the test")

    monkeypatch.setattr(MotionStepper, "advance_until", fail)
    after = publish(server, NS + len(before) * PERIOD, 2.0)  # beyond the look-ahead made before the failure
    out = before + after
    held = np.array([sample(o).held for o in out])
    moving = int(np.argmax(held))  # the first held sample: all before it moving, all after it held
    assert 0 < moving < len(out) and np.all(held[moving:]) and not np.any(held[:moving])
    np.testing.assert_array_equal([sample(o).q for o in out[:moving]],
                                  [truth.sample(k / RATE).q for k in range(moving)])
    for o in out[moving:]:
        np.testing.assert_array_equal(sample(o).q, sample(out[moving - 1]).q)
        assert np.all(sample(o).qd == 0.0) and np.all(np.isfinite(sample(o).effort))
    status = server.status(NS + len(out) * PERIOD)
    assert status.stream.state == ERROR and "injected by the test" in status.stream.last_error
    server.end()
    monkeypatch.undo()
    server.restart()
    assert server.stream.state == RUNNING
    server.begin(NS + len(out) * PERIOD)
    resumed = publish(server, NS + len(out) * PERIOD, 0.1)
    np.testing.assert_allclose(sample(resumed[0]).q, truth.sample(0.0).q, atol=1e-12)


def test_coming_to_rest_pauses_along_the_ramp(server: ReferenceServer) -> None:
    server.begin(NS)
    publish(server, NS, 0.3)
    server.end()  # not publishing: the pause is applied at the next frame to make, and nothing to wait for
    server.come_to_rest(NS + 30 * PERIOD)
    assert server.stream.state == PAUSED and server.stream.target_speed == 0.0


def test_the_solver_process_serves_the_same_frames_and_raises_its_errors() -> None:
    """Frames from the child process equal those made here, bit for bit; an unreachable target raises
    UnreachableTargetError through the pipe and leaves the stream as it was; closing ends the process."""
    here = ReferenceServer(LocalSolver(spec()), RATE, LEAD, Preview(0.2, 4, 10))
    process = SolverProcess(spec())
    there = ReferenceServer(process, RATE, LEAD, Preview(0.2, 4, 10))
    try:
        with pytest.raises(UnreachableTargetError):
            there.check_targets(Task(30.0, 2.0, 0.2, 5.0))
        for served in (here, there):
            served.begin(NS)
        a, b = publish(here, NS, 1.2), publish(there, NS, 1.2)
        assert [o.k for o in a] == [o.k for o in b]
        for x, y in zip(a, b, strict=True):
            np.testing.assert_array_equal(sample(x).q, sample(y).q)
            np.testing.assert_array_equal(sample(x).effort, sample(y).effort)
        assert there.stream.targets == load_config().task
    finally:
        here.close()
        there.close()
    with pytest.raises(ProcessLookupError):
        os.kill(process.pid, 0)  # ended and reaped


def test_a_stop_flag_set_from_another_thread_ends_computing_ahead_within_a_step() -> None:
    """A request that computes a minute ahead without a budget ends soon after another thread sets the stop
    flag (a command waits), within the compiled run under way: no frames are made, the batch says the motion is
    short of what was asked (busy), and far less than the minute is computed."""
    solver = StreamSolver(spec())
    schedule = FrameSchedule(RATE, RATE, LEAD, 1.0, solver.stream.sample(0.0))
    timer = threading.Timer(0.3, solver.stop.__setitem__, (0, 1))
    timer.start()
    batch = solver.frames(schedule.request(schedule.plan(), 10, 60.0, 4, 10, None), 2.0)
    timer.cancel()
    assert batch.busy and not len(batch.frames)  # the waiting request comes first; the frames on the next call
    assert 0.0 < solver.stream.computed_until < 30.0


def test_the_solver_process_obeys_an_interrupt_that_comes_before_or_during_a_frame_request_once() -> None:
    """An interrupt sent before a frame request (raced with it: the request was on its way) ends it early
    (busy) and is cleared with it, so the next one runs whole; one sent before another request is cleared
    before it (a command's own frames are made whole); one sent while a request computes a minute of motion
    ahead ends that request early, and the process goes on answering."""
    process = SolverProcess(spec())
    try:
        schedule = FrameSchedule(RATE, RATE, LEAD, 1.0, process.info.start)
        process.interrupt()
        assert process.frames(schedule.request(schedule.plan(), 10, 60.0, 4, 10, None), 4.0).busy
        assert not process.frames(schedule.request(schedule.plan(), 10, 1.0, 4, 10, None), 4.0).busy
        process.interrupt()
        process.refresh_status()
        assert not process.frames(schedule.request(schedule.plan(), 10, 2.0, 4, 10, None), 4.0).busy
        replies = []
        long = schedule.request(schedule.plan(), 10, 60.0, 4, 10, None)
        worker = threading.Thread(target=lambda: replies.append(process.frames(long, 4.0)))
        worker.start()
        time.sleep(0.5)
        process.interrupt()
        worker.join(60.0)
        assert replies and replies[0].busy
        assert process.refresh_status() is not None
    finally:
        process.close()


def test_a_hung_solver_process_is_killed_and_reported_and_the_server_holds(monkeypatch) -> None:
    """The solver process stopped (SIGSTOP, as a debugger, swapping or a stuck process leaves it): a request to it
    raises SolverHungError once no beat came for HUNG_AFTER (a bound the test shortens), the process is killed
    and reaped, and the server holds its last sample, stopped, reporting the reason; closing it does not wait."""
    monkeypatch.setattr(solver_module, "HUNG_AFTER", 0.3)
    process = SolverProcess(spec())
    server = ReferenceServer(process, RATE, LEAD, Preview(0.2, 4, 10))
    try:
        server.begin(NS)
        publish(server, NS, 0.2)
        os.kill(process.pid, signal.SIGSTOP)
        with pytest.raises(CommandRefusedError, match=r"gave no sign of life .* killed"):
            server.check_targets(Task(3.1, 2.0, 0.2, 5.0))
        assert process.exit_code == -signal.SIGKILL  # reaped: its exit status collected
        assert not server.computing and "gave no sign of life" in server.schedule.fault
        assert not server.come_to_rest(NS + 30 * PERIOD)  # nothing to ramp: the last sample is held
    finally:
        server.close()
    with pytest.raises(ProcessLookupError):
        os.kill(process.pid, 0)


def test_closing_ends_a_live_solver_process_by_request_and_kills_a_stopped_one_without_its_timeout() -> None:
    """``close``: a live solver process, asked to end, ends by itself (exit code 0, not a kill); a stopped one
    (SIGSTOP) gives no beat and is killed after HUNG_AFTER, long before the close's timeout."""
    live = SolverProcess(spec())
    live.close(timeout=60.0)
    assert live.exit_code == 0
    process = SolverProcess(spec())
    os.kill(process.pid, signal.SIGSTOP)
    start = time.monotonic()
    process.close(timeout=60.0)  # no beat for HUNG_AFTER: killed
    assert process.exit_code == -signal.SIGKILL
    assert time.monotonic() - start < 10.0  # not after the timeout (60 s)


def test_a_new_preview_applies_to_the_frames_made_after_it(server: ReferenceServer) -> None:
    """A preview changed (the node's preview.* parameters) reaches the frame worker: the frames made after the
    change (here all, made again after a command at the first frame) carry previews over the new horizon with the
    new points, each point the stream's sample at its time."""
    server.preview = Preview(0.5, 6, 10)
    server.command("speed_scaling", 1.0, accepted_ns=0)  # not publishing: from the next frame to publish on
    wait_ready(server)
    server.begin(NS)
    out = publish(server, NS, 0.5)
    previews = [(sample(o).t, o.frames.previews[o.row]) for o in out if o.row in o.frames.previews]
    assert len(previews) == 5 and all(preview.t.size == 6 for _, preview in previews)  # points after the frame's
    truth = ReferenceStream(load_config(), "rigid", STEP, blend_time=0.5, ramp_time=0.3)
    truth.compute(1.0)
    for frame_t, preview in previews:
        assert preview.t[-1] - frame_t == pytest.approx(0.5, abs=1e-9)
        np.testing.assert_allclose(preview.q, [truth.sample(t).q for t in preview.t], atol=1e-12)


def test_replies_name_a_sample_by_its_stamp_only_once_published(server: ReferenceServer) -> None:
    """Before publishing, a command's sample has no stamp yet: the reply names it by its number."""
    reply = pause_reply(server, True, accepted_ns=0)
    assert reply.success and "sample 0 of the stream (stamped once published)" in reply.message, reply.message
    pause_reply(server, False, accepted_ns=0)
    server.begin(5 * NS)
    publish(server, 5 * NS, 0.2)
    reply = pause_reply(server, True, accepted_ns=5 * NS + 20 * PERIOD)
    k = round((float(reply.message.split("stamped ")[1].split(" s")[0]) * NS - 5 * NS) / PERIOD)
    assert reply.success and k >= 20, reply.message  # by its stamp, at or after the acceptance


def test_health_ranks_what_is_wrong_worst_first() -> None:
    """Diagnostics' level and message (ROS-free): before publishing, what the node does or, at ERROR, why it
    cannot start; while publishing, a stopped solver over a failed stream over a clock that went back over a
    forward leap over samples held late, else OK with the stream's state."""
    assert startup_health("configuring: starting the solver") == Health(Level.OK, "configuring: starting the solver")
    assert startup_health("cannot configure: bad file").level == Level.ERROR
    stream = StreamStatus(RUNNING, Task(), 1.0, "", 1.0, 0.0)
    status = ServerStatus(stream=stream, publishing=True, last=None, counters={"held_late": 0}, fault="",
                          frames_ready=100)
    assert serving_health(status, 0) == Health(Level.OK, RUNNING)
    late = serving_health(status, 3)
    assert late.level == Level.WARN and "3 samples held" in late.message
    leapt = dataclasses.replace(status, clock_note="ROS time leapt forward by 5 s")
    assert serving_health(leapt, 3) == Health(Level.WARN, f"{RUNNING}: ROS time leapt forward by 5 s")
    behind = dataclasses.replace(leapt, clock_behind=0.25)
    assert serving_health(behind, 3).level == Level.WARN and "went back" in serving_health(behind, 3).message
    failed = dataclasses.replace(behind, stream=dataclasses.replace(stream, state=ERROR, last_error="singular"))
    health = serving_health(failed, 3)
    assert health.level == Level.ERROR and health.message.startswith(f"{ERROR}: singular; the reference runs to its")
    assert "~/restart" in health.message and "configure" in health.message  # the remedies
    stopped = dataclasses.replace(failed, computing=False, fault="the solver process ended")
    health = serving_health(stopped, 3)
    assert health.level == Level.ERROR and health.message.startswith("solver stopped: the solver process ended")


def test_a_restart_takes_the_shortest_way_on_whole_turn_coordinates() -> None:
    """The column slews more than half a turn, then ~/restart goes back to the start: the column goes the
    shortest way (a jump of at most half a turn), to the same pose as the static-equilibrium start (whole turns
    apart), and the motion from there is the start's motion shifted by those turns."""
    solver = LocalSolver(spec(step=5e-4))
    stream = solver.solver.stream
    column = stream.joint_names.index("column_slew")
    assert stream.whole_turn_coordinates()[column] and not stream.whole_turn_coordinates()[0]  # base_x
    tau = 8.0
    stream.compute(tau)
    before = stream.sample(tau).q
    assert abs(before[column]) > np.pi  # the column has slewed more than half a turn
    answer = StreamSolver.restart(solver.solver, tau)
    assert np.array_equal(answer.before, before)
    assert abs(answer.start[column] - before[column]) <= np.pi
    fresh = ReferenceStream(load_config(), "rigid", 5e-4, 0.5, load_config().task, ramp_time=0.3)
    turns = (answer.start[column] - fresh.sample(0.0).q[column]) / (2.0 * np.pi)
    assert round(turns) != 0 and abs(turns - round(turns)) < 1e-12
    shift = np.zeros_like(before)
    shift[column] = 2.0 * np.pi * round(turns)
    np.testing.assert_allclose(answer.start, fresh.sample(0.0).q + shift, rtol=0, atol=1e-12)
    stream.compute(tau + 1.0)
    fresh.compute(1.0)
    np.testing.assert_allclose(stream.sample(tau + 1.0).q, fresh.sample(1.0).q + shift, rtol=0, atol=1e-9)


def test_the_worker_thread_is_named_for_the_operating_system(server: ReferenceServer) -> None:
    """The kernel's record of the thread (/proc, what top -H and bench_node read) has the name."""
    worker = next(thread for thread in threading.enumerate() if thread.name == "ref_frames")
    with open(f"/proc/self/task/{worker.native_id}/comm", encoding="utf-8") as comm:
        assert comm.read().strip() == "ref_frames"
