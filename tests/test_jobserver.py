"""make's jobserver: parsing MAKEFLAGS, taking and giving back tokens, and how many workers a map then uses."""

from __future__ import annotations

import fcntl
import os
import shutil
import subprocess
import sys
import termios

import pytest

from fracture_cli.errors import StageError
from fracture_cli.system import jobserver, parallel

from conftest import REPO

TOKENS = b"abc"  # make writes '+'; distinct bytes show that exactly the bytes read go back (in any order)


# Every test starts outside make, with no jobserver client kept (see conftest).
pytestmark = pytest.mark.usefixtures("outside_make")


@pytest.fixture(autouse=True)
def forks_for_any_work(monkeypatch):
    """Items here cost microseconds: a bake's map would keep them in its own process (parallel.fork_pays)."""
    monkeypatch.setattr(parallel, "FORK_SECONDS", -1.0)


@pytest.fixture
def many_cores(monkeypatch):
    """Pretend 8 cores, so the tokens, not the cores, bound the workers."""
    monkeypatch.setattr(parallel, "available_cores", lambda: 8)


@pytest.fixture
def pool_sizes(monkeypatch):
    """The worker count of every forked pool, and the tokens left in the pipe meanwhile (``waiting[0]``)."""
    sizes: list[int] = []
    left: list[int] = []
    waiting: list[int] = []
    original = parallel._run_forked

    def spy(function, shared, items, count):
        sizes.append(count)
        if waiting:
            left.append(_pending(waiting[0]))
        return original(function, shared, items, count)

    monkeypatch.setattr(parallel, "_run_forked", spy)
    return sizes, left, waiting


def _pending(fd: int) -> int:
    """Bytes waiting in the pipe ``fd`` belongs to."""
    return int.from_bytes(fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"), sys.byteorder)


def _all_back(pipe: tuple[int, int]) -> bool:
    """Whether the pipe holds TOKENS again (then left as it was)."""
    found = _drain(pipe[0])
    os.write(pipe[1], found)
    return sorted(found) == sorted(TOKENS)


def _drain(fd: int) -> bytes:
    os.set_blocking(fd, False)
    try:
        return os.read(fd, 4096)
    except BlockingIOError:
        return b""


@pytest.fixture
def make_pipe(monkeypatch):
    """A fake make 4.3 jobserver: an inheritable pipe holding TOKENS, named by MAKEFLAGS; yields its two ends."""
    read_fd, write_fd = os.pipe()
    for fd in (read_fd, write_fd):
        os.set_inheritable(fd, True)  # what make does for the descriptors it passes on
    os.write(write_fd, TOKENS)
    monkeypatch.setenv("MAKEFLAGS", f"s -j{len(TOKENS) + 1} --jobserver-auth={read_fd},{write_fd}")
    yield read_fd, write_fd
    jobserver.forget()
    os.close(read_fd)
    os.close(write_fd)


def _pid(_shared, item):
    return item, os.getpid()


def _fail_on_three(_shared, item):
    if item == 3:
        raise StageError(f"item {item} failed", stage="test")
    return item


def test_makeflags_parsing():
    parse = jobserver.parse_makeflags
    assert parse("") == jobserver.MakeFlags(parallel=False, auth=None)
    assert parse(" -j1") == jobserver.MakeFlags(parallel=False, auth=None)
    assert parse("s -j") == jobserver.MakeFlags(parallel=True, auth=None)
    assert parse("s -j2 --jobserver-auth=3,4") == jobserver.MakeFlags(parallel=True, auth="3,4")
    assert parse(" -j8 --jobserver-auth=fifo:/tmp/GMfifo1 --no-print-directory").auth == "fifo:/tmp/GMfifo1"
    assert parse("--jobserver-fds=5,6 -j3").auth == "5,6"
    assert parse("k -- JOBS=-j4 X=--jobserver-auth=3,4") == jobserver.MakeFlags(parallel=False, auth=None)


def test_outside_make_every_core():
    assert parallel.current_jobs() == parallel.available_cores()
    assert jobserver.client() is None


def test_serial_make_keeps_every_core(monkeypatch):
    monkeypatch.setenv("MAKEFLAGS", " -j1")
    assert parallel.current_jobs() == parallel.available_cores()


def test_parallel_make_without_jobserver_runs_one_job(monkeypatch, many_cores, pool_sizes):
    monkeypatch.setenv("MAKEFLAGS", "s -j")
    assert parallel.current_jobs() == 1
    assert {pid for _, pid in parallel.ordered_map(_pid, range(20))} == {os.getpid()}
    assert pool_sizes[0] == []


def test_closed_or_foreign_descriptors_are_no_jobserver(monkeypatch, tmp_path, many_cores):
    # make 4.3 closes the jobserver pipe for recipe lines it does not treat as recursive, MAKEFLAGS still names it.
    read_fd, write_fd = os.pipe()
    os.close(read_fd)
    os.close(write_fd)
    monkeypatch.setenv("MAKEFLAGS", f"-j2 --jobserver-auth={read_fd},{write_fd}")
    assert jobserver.client() is None
    assert parallel.current_jobs() == 1
    # The numbers reused by this process: a pipe of its own (not inheritable), a file; neither is read from.
    read_fd, write_fd = os.pipe()
    os.write(write_fd, TOKENS)
    with open(tmp_path / "f", "w") as fh:
        for auth in (f"{read_fd},{write_fd}", f"{fh.fileno()},{write_fd}", f"{read_fd},{read_fd}", "x,y", "-1,-1"):
            monkeypatch.setenv("MAKEFLAGS", f"-j2 --jobserver-auth={auth}")
            assert jobserver.client() is None, auth
            assert parallel.current_jobs() == 1, auth
    assert sorted(_drain(read_fd)) == sorted(TOKENS)
    os.close(read_fd)
    os.close(write_fd)


def test_pipe_tokens_bound_the_workers_and_go_back(make_pipe, many_cores, pool_sizes):
    sizes, left, waiting = pool_sizes
    waiting.append(make_pipe[0])
    assert parallel.current_jobs() == 8  # the bound; the free tokens decide per map
    results = parallel.ordered_map(_pid, range(40))
    assert [i for i, _ in results] == list(range(40))
    assert sizes == [1 + len(TOKENS)] and left == [0]
    assert len({pid for _, pid in results[1:]}) <= 1 + len(TOKENS)  # the first item ran here, before the fork
    assert _all_back(make_pipe)


def test_no_more_tokens_than_cores_or_items(make_pipe, monkeypatch, pool_sizes):
    sizes, left, waiting = pool_sizes
    waiting.append(make_pipe[0])
    monkeypatch.setattr(parallel, "available_cores", lambda: 2)
    parallel.ordered_map(_pid, range(40))
    monkeypatch.setattr(parallel, "available_cores", lambda: 8)
    parallel.ordered_map(_pid, range(3))  # the first item runs here before the map forks: two left
    assert sizes == [2, 2] and left == [len(TOKENS) - 1] * 2
    assert _all_back(make_pipe)


def test_no_free_token_runs_here(make_pipe, many_cores, pool_sizes):
    taken = _drain(make_pipe[0])  # make's other jobs hold every slot
    assert {pid for _, pid in parallel.ordered_map(_pid, range(20))} == {os.getpid()}
    assert pool_sizes[0] == []
    assert taken == TOKENS and _drain(make_pipe[0]) == b""


def test_tokens_go_back_when_the_work_raises(make_pipe, many_cores, monkeypatch):
    with pytest.raises(StageError, match="item 3 failed"):
        parallel.ordered_map(_fail_on_three, list(range(8)))
    assert _all_back(make_pipe)

    def interrupted(*_args):
        raise KeyboardInterrupt

    monkeypatch.setattr(parallel, "_run_forked", interrupted)
    with pytest.raises(KeyboardInterrupt):
        parallel.ordered_map(_pid, list(range(8)))
    assert _all_back(make_pipe)


def test_fifo_jobserver(monkeypatch, tmp_path, many_cores, pool_sizes):
    sizes, left, waiting = pool_sizes
    path = tmp_path / "GMfifo"
    os.mkfifo(path)
    make_end = os.open(path, os.O_RDWR | os.O_NONBLOCK)  # make 4.4 keeps the FIFO open while it runs
    try:
        os.write(make_end, TOKENS[:2])
        waiting.append(make_end)
        monkeypatch.setenv("MAKEFLAGS", f"-j3 --jobserver-auth=fifo:{path}")
        assert [i for i, _ in parallel.ordered_map(_pid, range(30))] == list(range(30))
        assert sizes == [3] and left == [0]
        assert sorted(_drain(make_end)) == sorted(TOKENS[:2])
    finally:
        jobserver.forget()
        os.close(make_end)
    monkeypatch.setenv("MAKEFLAGS", f"-j3 --jobserver-auth=fifo:{tmp_path / 'gone'}")
    assert parallel.current_jobs() == 1


def test_explicit_jobs_win_over_make(make_pipe, monkeypatch, many_cores, pool_sizes):
    sizes, left, waiting = pool_sizes
    waiting.append(make_pipe[0])
    with parallel.using(2):
        assert parallel.current_jobs() == 2
        parallel.ordered_map(_pid, range(20))
    parallel.ordered_map(_pid, range(20), jobs=3)
    assert sizes == [2, 3] and left == [len(TOKENS)] * 2  # no token taken
    monkeypatch.setenv("MAKEFLAGS", "-j")
    with parallel.using(2):
        assert parallel.current_jobs() == 2
    assert _all_back(make_pipe)


@pytest.mark.skipif(shutil.which("make") is None, reason="GNU make not installed")
def test_real_make_passes_its_jobserver_to_recursive_lines_only(tmp_path):
    # What make on this machine does: a '+' line gets the jobserver (two free slots of -j3), a plain line
    # may not (make 4.3 closes the pipe; 4.4's FIFO works for both).
    probe = tmp_path / "probe.py"
    probe.write_text("import sys\nsys.path.insert(0, sys.argv[1])\nfrom fracture_cli.system import jobserver\n"
                     "client = jobserver.client()\n"
                     "if client is None:\n    print('none', jobserver.default_jobs(8))\n"
                     "else:\n    with client.tokens(5) as extra:\n        print('tokens', extra)\n")
    (tmp_path / "Makefile").write_text(f"plus:\n\t+@{sys.executable} probe.py {REPO}\n"
                                       f"plain:\n\t@{sys.executable} probe.py {REPO}\n")
    env = {k: v for k, v in os.environ.items() if k not in ("MAKEFLAGS", "MFLAGS", "MAKELEVEL")}

    def run(*args):
        done = subprocess.run(["make", "-s", *args], cwd=tmp_path, env=env, check=True, capture_output=True,
                              text=True)
        assert "jobserver" not in done.stderr  # make checks at exit that every token came back
        return done.stdout.split()

    assert run("-j3", "plus") == ["tokens", "2"]
    assert run("-j3", "plain") in (["none", "1"], ["tokens", "2"])
    assert run("plain") == ["none", "8"]


@pytest.mark.skipif(shutil.which("make") is None, reason="GNU make not installed")
def test_asset_rules_get_the_jobserver_but_stay_dry_under_make_n(tmp_path):
    generated = subprocess.run([sys.executable, os.path.join(REPO, "scripts", "assets_mk.py")], check=True,
                               capture_output=True, text=True).stdout
    assert "\t$(JOBSERVER)$(FRACTURE) bake " in generated
    variables = [line for line in generated.splitlines() if line.startswith(("JOBSERVER =", "MAKE_LETTERS ="))]
    assert len(variables) == 2
    # The generated prefix on a recipe that records whether it got a usable jobserver.
    probe = ("import sys; sys.path.insert(0, sys.argv[1]); from fracture_cli.system import jobserver; "
             "open('ran', 'w').write(str(jobserver.client() is not None))")
    rule = f'.PHONY: all\nall:\n\t$(JOBSERVER){sys.executable} -c "{probe}" {REPO}\n'
    (tmp_path / "Makefile").write_text("\n".join(variables) + "\n" + rule)
    env = {k: v for k, v in os.environ.items() if k not in ("MAKEFLAGS", "MFLAGS", "MAKELEVEL")}
    for flags in (["-n", "-j2"], ["-t", "-j2"], ["-q", "-j2"]):
        subprocess.run(["make", "-s", *flags], cwd=tmp_path, env=env, capture_output=True)
        assert not (tmp_path / "ran").exists(), flags
    subprocess.run(["make", "-s", "-j2"], cwd=tmp_path, env=env, check=True, capture_output=True)
    assert (tmp_path / "ran").read_text() == "True"
