"""The stem lock is taken over only from a dead owner (pid and start time), never from a live one (issue 38).

docs/OUTPUTS.md: a lock whose owner ran on this host is stale only when that
process no longer runs (its pid gone, or reused by a process that started at
another time, or the machine rebooted since); a live owner's lock is never
broken, however long its heartbeat pauses; a waiter says once whom it waits
for, and gives up after its timeout with one line naming the lock and the pid.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time

import pytest

from fracture_cli.errors import OutputError
from fracture_cli.io import stemlock
from fracture_cli.io.outputs import output_names, output_set, verify_output_set
from fracture_cli.io.stemlock import StemLock, owner_state, process_start

linux_proc = pytest.mark.skipif(process_start(os.getpid()) is None, reason="no /proc/<pid>/stat here")


def write_lock(lock: StemLock, **info) -> None:
    owner = {"host": stemlock.socket.gethostname(), "token": "theirs", "started": "2026-01-01 00:00:00", **info}
    with open(lock.path, "w") as fh:
        json.dump(owner, fh)


def dead_pid() -> int:
    done = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    return int(done.stdout)


@pytest.fixture
def sleeper():
    """A live process that is not this one (the owner of a lock under test)."""
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
    yield proc
    proc.kill()
    proc.wait()


def fake_set(staging, tag: str) -> None:
    for name in output_names(staging.stem)[:-1]:
        with open(staging.file(name), "w") as fh:
            fh.write(f"{tag} {name}\n")
    staging.write_report({"tag": tag})


def test_the_lock_records_pid_start_time_and_boot(tmp_path):
    with StemLock(str(tmp_path), "s") as lock:
        with open(lock.path) as fh:
            info = json.load(fh)
        assert info["pid"] == os.getpid() and info["start_ticks"] == process_start(os.getpid())
        assert info["boot_id"] == stemlock.boot_id()
        assert owner_state(info) == "alive"
    assert not os.path.exists(lock.path)


def test_a_stale_lock_of_a_dead_pid_is_taken_over(tmp_path, caplog):
    lock = StemLock(str(tmp_path), "s")
    write_lock(lock, pid=dead_pid(), start_ticks=12345)
    started = time.monotonic()
    with caplog.at_level(logging.WARNING, logger="fracture_cli"):
        with output_set(str(tmp_path), "s", lock_timeout=30) as staging:
            fake_set(staging, "new")
    assert time.monotonic() - started < 5  # at once, not after STALE_SECONDS
    assert verify_output_set(str(tmp_path), "s") is None and not os.path.exists(lock.path)
    [line] = [r.getMessage() for r in caplog.records if "stale" in r.getMessage()]
    assert lock.path in line and "no longer runs" in line


@linux_proc
def test_a_lock_whose_pid_was_reused_is_taken_over(tmp_path, sleeper):
    """The pid runs, but it is another process than the one that wrote the lock (it started at another time)."""
    lock = StemLock(str(tmp_path), "s")
    start = process_start(sleeper.pid)
    assert start is not None
    write_lock(lock, pid=sleeper.pid, start_ticks=start - 1)
    assert owner_state(json.load(open(lock.path))) == "dead"
    assert lock.acquire(timeout=5)
    lock.release()
    assert not os.path.exists(lock.path)


def test_a_lock_from_before_a_reboot_is_taken_over(tmp_path, sleeper):
    if stemlock.boot_id() is None:
        pytest.skip("no boot id here")
    lock = StemLock(str(tmp_path), "s")
    write_lock(lock, pid=sleeper.pid, start_ticks=process_start(sleeper.pid), boot_id="an-earlier-boot")
    assert lock.acquire(timeout=5)
    lock.release()


@pytest.mark.parametrize("recorded", ["start", "no start"])
def test_a_live_owners_lock_is_never_broken(tmp_path, sleeper, monkeypatch, caplog, recorded):
    """Its heartbeat stopped (a bake stopped with Ctrl-Z, or busy in native code): still not stale on this host.

    The lock of an older version (no start time) counts as alive while its pid runs.
    """
    monkeypatch.setattr(stemlock, "STALE_SECONDS", 0.2)
    lock = StemLock(str(tmp_path), "s")
    start = {"start_ticks": process_start(sleeper.pid)} if recorded == "start" else {}
    write_lock(lock, pid=sleeper.pid, **start)
    before = open(lock.path).read()
    with caplog.at_level(logging.WARNING, logger="fracture_cli"):
        with pytest.raises(OutputError) as refused:
            with output_set(str(tmp_path), "s", lock_timeout=1.0) as staging:
                fake_set(staging, "new")
    message = str(refused.value)
    assert message.startswith(f"{lock.path}: another bake (pid {sleeper.pid} on "), message
    assert "waited 1 s" in message and "\n" not in message
    assert open(lock.path).read() == before  # not broken, not replaced
    assert not [n for n in os.listdir(tmp_path) if n != os.path.basename(lock.path)]  # nothing written
    waiting = [r.getMessage() for r in caplog.records]
    assert len(waiting) == 1 and waiting[0].startswith(f"{lock.path}: another bake (pid {sleeper.pid} ")
    assert "waiting for it" in waiting[0]


_HOLDER = r"""
import sys, time
sys.path.insert(0, sys.argv[1])
from fracture_cli.io.stemlock import StemLock
with StemLock(sys.argv[2], "s"):
    print("locked", flush=True)
    time.sleep(float(sys.argv[3]))
"""


def test_a_concurrent_bake_waits_for_the_live_owner_then_publishes(tmp_path):
    """Another process holds the lock (with its heartbeat): this bake waits for it, then takes the lock."""
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    holder = subprocess.Popen([sys.executable, "-c", _HOLDER, repo, str(tmp_path), "1.5"], stdout=subprocess.PIPE,
                              text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline() == "locked\n"
        started = time.monotonic()
        with output_set(str(tmp_path), "s", lock_timeout=60) as staging:
            fake_set(staging, "after")
        assert time.monotonic() - started >= 1.0  # it waited for the owner
    finally:
        holder.wait(timeout=60)
    assert holder.returncode == 0
    assert sorted(os.listdir(tmp_path)) == sorted(output_names("s"))


def _ctrl_c_inside(monkeypatch, name: str) -> None:
    """Make ``stemlock.<name>`` send this process a SIGINT half-way through (what a Ctrl-C at that moment does)."""
    real = getattr(stemlock, name)

    def interrupted(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)  # the handler would run here
        return real(*args, **kwargs)

    monkeypatch.setattr(stemlock, name, interrupted)


@pytest.mark.skipif(threading.current_thread() is not threading.main_thread(), reason="signals: main thread only")
@pytest.mark.parametrize("moment", ["process_start", "boot_id", "_read_lock"])
def test_a_ctrl_c_while_the_lock_is_made_or_removed_leaves_none(tmp_path, monkeypatch, moment):
    """The sweep once found ``.<stem>.fracture-lock`` left by a Ctrl-C in the preflight: it is now raised after."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        lock = StemLock(str(tmp_path), "s")
        if moment == "_read_lock":  # in release(): after the heartbeat stopped, before the file goes
            lock.acquire(timeout=0)
            _ctrl_c_inside(monkeypatch, moment)
            with pytest.raises(KeyboardInterrupt):
                lock.release()
        else:  # in acquire(): while the owner record is written
            _ctrl_c_inside(monkeypatch, moment)
            with pytest.raises(KeyboardInterrupt):
                lock.acquire(timeout=0)
    finally:
        signal.signal(signal.SIGINT, previous)
    assert os.listdir(tmp_path) == []
