"""A run's close-up that fails (its disk full, its folder gone) still closes the hub: the
run ends as a fault that says why, and the hub's process exits.

Before, a manifest that could not be written at the end raised past the session's close,
and the process never ended: Zenoh's callback threads, still declared, kept the
interpreter waiting at exit.
"""

from __future__ import annotations

import errno
import json
import subprocess
import sys
import textwrap

from hub.bus import open_session
from hub.loop import Hub
from hub.record import Recorder
from tests.conftest import TEST_ENDPOINTS
from tests.harness import harness

# The hub's last write of the manifest (the run's end) fails as on a full disk.
FULL_DISK_AT_THE_END = textwrap.dedent(
    """
    import errno, sys
    import hub.manifest
    from hub.cli import main

    write = hub.manifest.write_manifest

    def write_manifest(run_dir, manifest):
        if manifest["outcome"] != "running":
            raise OSError(errno.ENOSPC, "No space left on device", str(run_dir))
        write(run_dir, manifest)

    hub.manifest.write_manifest = write_manifest
    sys.exit(main(sys.argv[1:]))
    """
)


def test_a_manifest_that_cannot_be_written_at_the_end_is_a_fault_and_the_hub_exits(
    tmp_path, bus_overrides
):
    sets = [a for item in TEST_ENDPOINTS + bus_overrides for a in ("--set", item)]
    cmd = [sys.executable, "-c", FULL_DISK_AT_THE_END, "run", "--quiet", *sets]
    cmd += ["--duration-s", "0.2", "--runs-dir", str(tmp_path / "runs")]
    # hanging (the fault) fails the test by its timeout
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr[-3000:]
    assert "run failed: the run's record could not be closed" in done.stderr
    assert "No space left on device" in done.stderr
    assert "Traceback" not in done.stderr, done.stderr[-3000:]


class FullDisk:
    """A record file that takes ``room`` bytes, then fails as a full disk does."""

    def __init__(self, file, room: int):
        self.file, self.room = file, room
        self.closed = False

    def write(self, data: bytes) -> int:
        self.room -= len(data)
        if self.room < 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        return self.file.write(data)

    def flush(self) -> None:
        self.file.flush()

    def fileno(self) -> int:
        return self.file.fileno()

    def close(self) -> None:
        self.closed = True
        self.file.close()


def test_a_record_that_cannot_be_written_during_the_steps_stops_the_run_as_a_fault(
    tmp_path, bus_overrides, monkeypatch
):
    class RecorderOnAFullDisk(Recorder):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self._file = FullDisk(self._file, room=20_000)

    monkeypatch.setattr("hub.manifest.Recorder", RecorderOnAFullDisk)
    with harness(tmp_path, bus_overrides, "experiment.duration_s=60", "record.flush_s=0.05") as h:
        result = Hub(h.cfg, run_dir=h.run_dir).run()
        # its session closed: the hub's address is free for another router
        open_session(h.cfg.bus, listener=True).close()
    assert result.outcome == "fault" and 0 < result.steps < 6000
    assert result.reason.startswith("the run's record could not be written to ")
    assert "No space left on device" in result.reason
    manifest = json.loads((h.run_dir / "manifest.json").read_text())
    assert (manifest["outcome"], manifest["reason"]) == ("fault", result.reason)
    assert manifest["steps"] == result.steps
    # the endpoints were told the run ended, and made themselves safe
    assert h.exit_codes == {"body": 0, "culture": 0}


def test_a_part_of_the_close_up_that_fails_still_leaves_the_run_closed_as_a_fault(
    tmp_path, bus_overrides, monkeypatch
):
    """A bug raised in the body's final stop (as a half-updated module once did) left the
    manifest saying "running": the rest of the close-up never ran."""

    def broken(self, next_event):
        raise NameError("name '_bounds_s' is not defined")

    monkeypatch.setattr("hub.traffic.Traffic.stop_body", broken)
    with harness(tmp_path, bus_overrides, "experiment.duration_s=0.2") as h:
        result = Hub(h.cfg, run_dir=h.run_dir).run()
    assert result.outcome == "fault" and result.steps == 20
    assert "the body's final stop failed (NameError: name '_bounds_s'" in result.reason
    manifest = json.loads((h.run_dir / "manifest.json").read_text())
    assert (manifest["outcome"], manifest["reason"]) == ("fault", result.reason)
    assert h.exit_codes == {"body": 0, "culture": 0}  # told the run ended all the same
