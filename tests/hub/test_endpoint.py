"""What Endpoint.serve does on the bus: one output per valid input, drops counted, the
input timeout, describe answered, a failing step ends serve with its error, close always."""

from __future__ import annotations

import queue
import secrets
import threading

import numpy as np
import pytest

from hub.bus import free_tcp_port, open_session, payload_bytes
from hub.config import BusSection
from hub.protocol import Description, MotorCommand, SensorReading
from tests.endpoints import EchoBody
from tests.harness import wait_for


class RecordingBody(EchoBody):
    """The echo body, noting the timeouts and the close it is given."""

    def __init__(self, fail_at_step: int | None = None):
        super().__init__("0")
        self.input_timeout_s = 0.2
        self.fail_at_step = fail_at_step
        self.timeouts = 0
        self.closed = False

    def step(self, m):
        if m.step == self.fail_at_step:
            raise RuntimeError(f"device fault at step {m.step}")
        return super().step(m)

    def on_input_timeout(self):
        self.timeouts += 1

    def close(self):
        self.closed = True


class Served:
    """An endpoint serving in a thread, and a hub-side session talking to it."""

    def __init__(self, endpoint):
        port = free_tcp_port()
        self.bus = BusSection(
            session=f"test-{secrets.token_hex(4)}", listen=(f"tcp/127.0.0.1:{port}",)
        )
        self.keys = self.bus.keys
        self.endpoint = endpoint
        self.session = open_session(self.bus, listener=True)
        self.replies: queue.SimpleQueue = queue.SimpleQueue()
        self.alive = threading.Event()
        self._declared = [
            self.session.declare_subscriber(
                self.keys.sensors("0"), lambda s: self.replies.put(payload_bytes(s))
            ),
            self.session.liveliness().declare_subscriber(
                self.keys.alive("body", "0"), lambda s: self.alive.set(), history=True
            ),
        ]
        self.motor = self.session.declare_publisher(self.keys.motor("0"))
        self.error: BaseException | None = None
        self.status: int | None = None
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()
        assert self.alive.wait(10), "the endpoint did not come up"

    def _serve(self):
        try:
            self.status = self.endpoint.serve(self.bus, install_signals=False)
        except BaseException as exc:
            self.error = exc

    def send(self, step: int) -> None:
        self.motor.put(MotorCommand(step, 0.1, 0.2).encode())

    def reply(self, timeout_s: float = 5.0) -> SensorReading:
        return SensorReading.decode(self.replies.get(timeout=timeout_s))

    def describe(self) -> Description:
        replies = list(self.session.get(self.keys.describe("body", "0"), timeout=5.0))
        return Description.decode(payload_bytes(replies[0].ok))

    def stop(self) -> None:
        self.endpoint.request_stop()
        self.thread.join(10)
        self.session.close()


@pytest.fixture
def served():
    started = []

    def start(endpoint):
        started.append(Served(endpoint))
        return started[-1]

    yield start
    for s in started:
        if s.thread.is_alive():
            s.stop()


def test_each_input_is_answered_once_with_an_output_of_its_step(served):
    s = served(RecordingBody())
    for k in range(5):
        s.send(k)
        reading = s.reply()
        assert reading.step == k
        np.testing.assert_allclose(reading.pose, [k, 0.1, 0.2])
    s.stop()
    assert s.status == 0 and s.error is None
    assert s.endpoint.steps == 5


def test_stale_and_malformed_inputs_are_dropped_counted_and_described(served):
    s = served(RecordingBody())
    s.send(0)
    s.send(1)
    assert [s.reply().step, s.reply().step] == [0, 1]
    s.send(1)  # stale: already stepped
    s.motor.put(b"\xc1 not msgpack")
    s.send(2)
    assert s.reply().step == 2  # the run goes on
    counters = s.describe().counters
    assert counters["dropped"] == {"stale": 1, "not_msgpack": 1}
    assert counters["steps"] == 3
    assert s.replies.empty()


def test_silence_calls_the_input_timeout_once_until_inputs_come_again(served):
    body = RecordingBody()
    s = served(body)
    wait_for(lambda: body.timeouts == 1, timeout_s=5)
    s.send(0)
    s.reply()
    wait_for(lambda: body.timeouts == 2, timeout_s=5)
    s.stop()
    assert body.timeouts == 2


def test_a_failing_step_ends_serve_with_its_error_and_closes_the_device(served):
    body = RecordingBody(fail_at_step=1)
    s = served(body)
    s.send(0)
    s.reply()
    s.send(1)
    s.thread.join(10)
    assert not s.thread.is_alive()
    assert isinstance(s.error, RuntimeError) and "step 1" in str(s.error)
    assert body.closed
    s.session.close()


def test_a_stop_request_ends_serve_cleanly_and_closes_the_device(served):
    body = RecordingBody()
    s = served(body)
    s.stop()
    assert not s.thread.is_alive()
    assert s.status == 0 and body.closed
