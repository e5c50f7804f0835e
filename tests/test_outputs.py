"""The output-set protocol under faults (issue 13): outputs replaced as a set or not at all, inputs never touched.

Library-level tests drive :func:`fracture_cli.io.outputs.output_set` with
small files (milliseconds); CLI tests bake a box once into a "previous" set
and re-bake it with a fault injected, asserting the exact outcome: exit code,
one error line naming the file, and which set is on disk afterwards.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from click.testing import CliRunner

from fracture_cli.cli import cli
from fracture_cli.errors import OutputError
from fracture_cli.io import outputs, stemlock
from fracture_cli.io import preflight as preflight_module
from fracture_cli.io.outputs import output_names, output_set, verify_output_set
from fracture_cli.io.preflight import preflight
from fracture_cli.io.stemlock import StemLock

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
SMALL = ["--set", "cage.target_faces=500", "--set", "modes.num_modes=3"]
NEW = ["--set", "fragments.interior_color=[0.1, 0.9, 0.1, 1.0]", "--set", "runtime.threshold=2.5"]


def snapshot(folder) -> dict[str, bytes]:
    """Every file and folder under ``folder`` (hidden ones too) with its bytes."""
    out = {}
    for root, dirs, files in os.walk(folder):
        for d in dirs:
            out[os.path.relpath(os.path.join(root, d), folder) + "/"] = b""
        for f in files:
            with open(os.path.join(root, f), "rb") as fh:
                out[os.path.relpath(os.path.join(root, f), folder)] = fh.read()
    return out


def error_lines(result) -> list[str]:
    return [line for line in result.stderr.splitlines() if line.startswith("error:")]


def assert_one_line(result, *needles):
    output = result.output + result.stderr
    assert "Traceback" not in output and "internal error" not in output, output
    lines = error_lines(result)
    assert len(lines) == 1, result.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]


# ---------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def asset(tmp_path_factory) -> str:
    folder = tmp_path_factory.mktemp("asset")
    shutil.copy(os.path.join(HERE, "data", "bad", "uv_seams.obj"), folder / "box.obj")
    return str(folder / "box.obj")


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> str:
    return str(tmp_path_factory.mktemp("cache"))


@pytest.fixture(scope="module")
def previous(asset, cache, tmp_path_factory) -> str:
    """A folder holding one complete baked set of ``box`` (the 'old set')."""
    out = str(tmp_path_factory.mktemp("previous") / "out")
    result = CliRunner().invoke(cli, ["bake", asset, "-o", out, "--cache", cache, *SMALL])
    assert result.exit_code == 0, result.output
    assert verify_output_set(out, "box") is None
    return out


@pytest.fixture
def old_set(previous, tmp_path) -> tuple[str, dict[str, bytes]]:
    out = str(tmp_path / "out")
    shutil.copytree(previous, out)
    return out, snapshot(out)


def rebake(asset, out, cache, *extra, **kwargs):
    return CliRunner().invoke(cli, ["bake", asset, "-o", out, "--cache", cache, *SMALL, *NEW, *extra], **kwargs)


def fault_at_rename(monkeypatch, out: str, number: int, fault) -> None:
    """Call ``fault()`` just before the ``number``-th rename that publishes a staged file into ``out``."""
    real_replace, real_out, calls = os.replace, os.path.realpath(out), []

    def replace(src, dst, **kw):
        if os.path.dirname(os.path.realpath(dst)) == real_out and ".staging-" in os.fspath(src):
            calls.append(dst)
            if len(calls) == number:
                fault()
        return real_replace(src, dst, **kw)

    monkeypatch.setattr(os, "replace", replace)


def raise_(exc):
    def fault():
        raise exc
    return fault


# ---------------------------------------------------------------- faults during a bake (CLI)


def test_failure_between_renames_restores_the_previous_set(asset, cache, old_set, monkeypatch):
    out, before = old_set
    fault_at_rename(monkeypatch, out, 3, raise_(OSError(errno.EIO, "Input/output error")))  # two new files in place
    result = rebake(asset, out, cache)
    assert result.exit_code == 1
    assert_one_line(result, out, "the previous outputs were restored")
    assert snapshot(out) == before  # byte for byte, and no staging folder or lock left


def test_ctrl_c_between_renames_finishes_the_new_set_then_stops(asset, cache, old_set, monkeypatch):
    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signals are delivered to the main thread only")
    out, before = old_set
    # A real SIGINT with one file of the new set in place.
    fault_at_rename(monkeypatch, out, 2, lambda: os.kill(os.getpid(), signal.SIGINT))
    previous_handler = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        result = rebake(asset, out, cache)
    finally:
        signal.signal(signal.SIGINT, previous_handler)
    assert result.exit_code == 130
    assert f"complete outputs were written for {os.path.join(out, 'box')}" in result.stderr
    assert verify_output_set(out, "box") is None
    after = snapshot(out)
    assert sorted(after) == sorted(before)
    assert after["box.glb"] != before["box.glb"] and after["box.fracture.json"] != before["box.fracture.json"]


@pytest.mark.parametrize("where", ["while writing", "inside a rename, off the main thread"])
def test_interrupt_keeps_the_previous_set(asset, cache, old_set, monkeypatch, where):
    """Ctrl-C while the files are written, or inside a rename where no signal handler can hold it back (a worker
    thread): the previous set stays, byte for byte (renames already done are undone)."""
    out, before = old_set
    if where == "while writing":
        monkeypatch.setattr("fracture_cli.runtime.format.write_runtime", lambda *a, **k: raise_(KeyboardInterrupt())())
    else:
        fault_at_rename(monkeypatch, out, 3, raise_(KeyboardInterrupt()))
        monkeypatch.setattr(outputs, "_in_main_thread", lambda: False)
    result = rebake(asset, out, cache)
    assert result.exit_code == 130
    assert "interrupted; no output was written (previous outputs are unchanged)" in result.stderr
    assert snapshot(out) == before


def test_disk_full_while_writing_keeps_the_previous_set(asset, cache, old_set, monkeypatch):
    out, before = old_set

    monkeypatch.setattr("fracture_cli.runtime.format.write_runtime",
                        lambda *a, **k: raise_(OSError(errno.ENOSPC, "No space left on device"))())
    result = rebake(asset, out, cache)
    assert result.exit_code == 1
    assert_one_line(result, out, "disk full while writing the outputs; the previous outputs are unchanged")
    assert snapshot(out) == before


def test_report_path_taken_by_a_folder_is_refused_before_work(asset, cache, old_set, monkeypatch):
    out, _ = old_set
    os.remove(os.path.join(out, "box.report.json"))
    os.mkdir(os.path.join(out, "box.report.json"))
    before = snapshot(out)
    monkeypatch.setattr("fracture_cli.stages.load.load_surface", lambda *a: pytest.fail("loaded before the check"))
    result = rebake(asset, out, cache)
    assert result.exit_code == 1
    assert_one_line(result, "box.report.json", "is in the way of an output")
    assert snapshot(out) == before


# ---------------------------------------------------------------- preflight (fast: nothing is baked)


@pytest.fixture
def no_load(monkeypatch):
    """Fail the test if a bake gets past its preflight."""
    monkeypatch.setattr("fracture_cli.stages.load.load_surface", lambda *a: pytest.fail("loaded before the check"))


def test_too_little_free_space_is_refused_before_work(asset, tmp_path, monkeypatch, no_load):
    monkeypatch.setattr(preflight_module, "free_bytes", lambda folder: 1000)
    result = CliRunner().invoke(cli, ["bake", asset, "-o", str(tmp_path / "out"), *SMALL])
    assert result.exit_code == 1
    assert_one_line(result, str(tmp_path / "out"), "only 1000 bytes free in the output folder; the outputs of box "
                                                   "need about")


def test_unwritable_output_folder_is_refused_before_work(asset, tmp_path, monkeypatch, no_load):
    out = tmp_path / "ro"
    out.mkdir()
    real_open = os.open

    def read_only(path, flags, *args, **kwargs):
        if os.path.dirname(os.path.abspath(os.fspath(path))) == str(out) and flags & os.O_CREAT:
            raise OSError(errno.EROFS, "Read-only file system", path)
        return real_open(path, flags, *args, **kwargs)

    monkeypatch.setattr(os, "open", read_only)
    result = CliRunner().invoke(cli, ["bake", asset, "-o", str(out), *SMALL])
    assert result.exit_code == 1
    assert_one_line(result, "the output folder is not writable (Read-only file system)")
    assert os.listdir(out) == []


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0,
                    reason="running as root: folder permissions do not apply (the simulated read-only test covers it)")
def test_read_only_folder_by_permissions(asset, tmp_path, no_load):
    out = tmp_path / "ro"
    out.mkdir()
    out.chmod(0o555)
    try:
        result = CliRunner().invoke(cli, ["bake", asset, "-o", str(out / "sub"), *SMALL])
        assert result.exit_code == 1
        assert_one_line(result, "cannot create the output folder (Permission denied)")
        result = CliRunner().invoke(cli, ["bake", asset, "-o", str(out), *SMALL])
        assert result.exit_code == 1
        assert_one_line(result, "the output folder is not writable (Permission denied)")
    finally:
        out.chmod(0o755)


def test_empty_output_folder_is_one_line(asset, no_load):
    result = CliRunner().invoke(cli, ["bake", asset, "-o", "", *SMALL])
    assert result.exit_code == 1
    assert_one_line(result, "box.obj", 'the output folder is "" (empty)')


def test_output_folder_that_is_a_file(asset, tmp_path, no_load):
    path = tmp_path / "file"
    path.write_text("not a folder")
    result = CliRunner().invoke(cli, ["bake", asset, "-o", str(path), *SMALL])
    assert result.exit_code == 2 and "is a file" in result.output  # click's own usage check
    with pytest.raises(OutputError, match="the output folder is a file, not a folder"):
        preflight(str(path), "box")  # the library says the same without the CLI
    assert path.read_text() == "not a folder"


@pytest.mark.skipif(sys.platform != "linux", reason="needs a file system that stores any bytes in names")
def test_non_utf8_file_name_is_one_line(asset, tmp_path, no_load):
    folder = os.fsencode(str(tmp_path))
    name = os.path.join(folder, b"caf\xe9.obj")
    shutil.copy(asset, name)
    result = CliRunner().invoke(cli, ["bake", os.fsdecode(name), "-o", str(tmp_path / "out"), *SMALL])
    assert result.exit_code == 1
    assert_one_line(result, "caf\\xe9.obj", "is not valid UTF-8")
    assert not os.path.exists(tmp_path / "out")


def test_an_input_is_never_an_output(asset, tmp_path, no_load):
    folder = tmp_path / "assets"
    folder.mkdir()
    glb = folder / "prop.glb"
    shutil.copy(os.path.join(HERE, "data", "bad", "two_materials.glb"), glb)
    original = glb.read_bytes()
    (tmp_path / "link").symlink_to(folder)
    elsewhere = tmp_path / "other"
    elsewhere.mkdir()
    os.link(glb, elsewhere / "prop.glb")  # the output name is a hard link to the input
    b = tmp_path / "b"
    b.mkdir()
    shutil.copy(asset, b / "x.obj")
    cases = [
        ([str(glb), "-o", str(folder)], "prop.glb"),  # the case: same folder, same stem
        ([str(glb), "-o", str(tmp_path / "link")], "prop.glb"),  # the same folder through a symlink
        ([str(glb), "-o", str(elsewhere)], "prop.glb"),  # a hard link
        ([str(b / "x.obj"), str(glb), "-o", str(folder)], "prop.glb"),  # a batch: another input's output
    ]
    for args, name in cases:
        result = CliRunner().invoke(cli, ["bake", *args, *SMALL])
        assert result.exit_code == 1, args
        assert_one_line(result, name, "which this command reads", "write the output elsewhere")
        assert glb.read_bytes() == original
    assert sorted(os.listdir(folder)) == ["prop.glb"]


def test_gltf_companion_file_is_never_an_output(tmp_path, no_load):
    sys.path.insert(0, os.path.join(HERE, "data"))
    from make_bad_corpus import Gltf, box_primitive

    g = Gltf()
    g.node(mesh=g.mesh([box_primitive(g)]))
    text, binary = g.gltf([0], "x.fracture.bin")  # the buffer has the name the runtime file would get
    (tmp_path / "x.gltf").write_text(text)
    (tmp_path / "x.fracture.bin").write_bytes(binary)
    result = CliRunner().invoke(cli, ["bake", str(tmp_path / "x.gltf"), "-o", str(tmp_path), *SMALL])
    assert result.exit_code == 1
    assert_one_line(result, "x.fracture.bin", "which this command reads")
    assert (tmp_path / "x.fracture.bin").read_bytes() == binary


# ---------------------------------------------------------------- the protocol (library level)


def fake_set(staging, tag: str) -> None:
    """Write a small, self-consistent set whose every file says ``tag``."""
    for name in output_names(staging.stem)[:-1]:
        with open(staging.file(name), "w") as fh:
            fh.write(f"{tag} {name}\n" * 50)
    staging.write_report({"tag": tag})


def test_published_files_get_0666_minus_umask(tmp_path):
    for mask, mode in ((0o022, 0o644), (0o027, 0o640)):
        old = os.umask(mask)
        try:
            with output_set(str(tmp_path), "m") as staging:
                fake_set(staging, "x")
        finally:
            os.umask(old)
        assert {oct(os.stat(tmp_path / n).st_mode & 0o777) for n in output_names("m")} == {oct(mode)}


def test_runtime_file_written_alone_is_0644(tmp_path):
    from fracture_cli.runtime.format import write_runtime
    from fracture_cli.stages.runtime import RuntimeOptions, runtime

    sys.path.insert(0, HERE)
    from test_runtime import slab_bar

    old = os.umask(0o022)
    try:
        paths = write_runtime(runtime(*slab_bar(k=3), RuntimeOptions()), tmp_path / "a.fracture.json")
    finally:
        os.umask(old)
    assert [oct(os.stat(p).st_mode & 0o777) for p in paths] == ["0o644", "0o644"]


def test_report_is_the_manifest_of_the_set(tmp_path):
    with output_set(str(tmp_path), "s") as staging:
        fake_set(staging, "one")
    report = json.loads((tmp_path / "s.report.json").read_text())
    assert sorted(report["files"]) == ["s.fracture.bin", "s.fracture.json", "s.glb"]
    assert verify_output_set(str(tmp_path), "s") is None
    (tmp_path / "s.glb").write_text("from another bake")
    assert "s.glb is not the file the report lists" in verify_output_set(str(tmp_path), "s")


def test_report_with_nan_is_refused(tmp_path):
    from fracture_cli.errors import StageError

    with pytest.raises(StageError, match=r"non-finite numbers at checks.volume_error"):
        with output_set(str(tmp_path), "n") as staging:
            for name in output_names("n")[:-1]:
                open(staging.file(name), "w").close()
            staging.write_report({"checks": {"volume_error": float("nan")}})
    assert os.listdir(tmp_path) == []


def test_stale_staging_folders_are_removed_and_a_journalled_one_completed(tmp_path):
    out = str(tmp_path)
    with output_set(out, "s") as staging:
        fake_set(staging, "old")
    # What killed bakes leave: an empty staging folder, an old-style one, and one killed while publishing.
    os.mkdir(tmp_path / ".s.bake-abcd1234")
    os.mkdir(tmp_path / (".s.staging-" + "0" * 32))
    publishing = tmp_path / (".s.staging-" + "1" * 32)
    publishing.mkdir()
    staging = outputs.Staging(out, "s", str(publishing))
    fake_set(staging, "new")
    (publishing / "PUBLISHING").write_text("\n".join(output_names("s")) + "\n")
    for name in output_names("s")[:2]:  # killed after two renames: a mixed set on disk
        os.replace(publishing / name, tmp_path / name)
    assert verify_output_set(out, "s") is not None
    os.mkdir(tmp_path / (".other.staging-" + "2" * 32))  # another stem's: not ours to touch
    preflight(out, "s")
    assert verify_output_set(out, "s") is None
    assert "new" in (tmp_path / "s.glb").read_text()
    assert sorted(os.listdir(tmp_path)) == sorted([*output_names("s"), ".other.staging-" + "2" * 32])


def test_optional_preview_is_published_with_the_set_and_removed_with_the_next(tmp_path):
    out = str(tmp_path)
    with output_set(out, "p") as staging:
        fake_set_with_preview(staging, "one")
    report = json.loads((tmp_path / "p.report.json").read_text())
    assert "p.preview.png" in report["files"] and verify_output_set(out, "p") is None
    (tmp_path / "p.preview.png").write_text("from another bake")
    assert "p.preview.png is not the file the report lists" in verify_output_set(out, "p")
    with output_set(out, "p") as staging:  # a bake without --preview: the older preview goes with the publish
        fake_set(staging, "two")
    assert not (tmp_path / "p.preview.png").exists() and verify_output_set(out, "p") is None


def test_failed_bake_keeps_the_previous_preview(tmp_path):
    out = str(tmp_path)
    with output_set(out, "p") as staging:
        fake_set_with_preview(staging, "one")
    with pytest.raises(RuntimeError), output_set(out, "p") as staging:
        fake_set(staging, "two")
        raise RuntimeError("a stage failed")
    assert "one" in (tmp_path / "p.preview.png").read_text() and verify_output_set(out, "p") is None


def test_killed_publish_that_removes_a_preview_is_completed(tmp_path):
    out = str(tmp_path)
    with output_set(out, "q") as staging:
        fake_set_with_preview(staging, "old")
    publishing = tmp_path / (".q.staging-" + "3" * 32)
    publishing.mkdir()
    staging = outputs.Staging(out, "q", str(publishing))
    fake_set(staging, "new")
    (publishing / "PUBLISHING").write_text("".join(n + "\n" for n in output_names("q")) + "-q.preview.png\n")
    os.replace(publishing / "q.fracture.bin", tmp_path / "q.fracture.bin")  # killed after one rename
    preflight(out, "q")
    assert verify_output_set(out, "q") is None and not (tmp_path / "q.preview.png").exists()


def fake_set_with_preview(staging, tag: str) -> None:
    with open(staging.file(staging.stem + ".preview.png"), "w") as fh:
        fh.write(f"{tag} preview\n")
    fake_set(staging, tag)


def test_stale_lock_of_a_dead_process_is_broken_and_a_live_one_waited_for(tmp_path, monkeypatch):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    lock = StemLock(str(tmp_path), "s")
    with open(lock.path, "w") as fh:
        json.dump({"host": stemlock.socket.gethostname(), "pid": int(dead.stdout), "token": "dead"}, fh)
    with output_set(str(tmp_path), "s") as staging:  # the dead owner's lock does not block
        fake_set(staging, "x")
    assert not os.path.exists(lock.path)
    with StemLock(str(tmp_path), "s"):  # a live owner (this process) holds it: the next waiter times out
        with pytest.raises(OutputError, match=r"another bake \(pid \d+ on .*\) is writing s\.\* here"):
            StemLock(str(tmp_path), "s", timeout=0.3).acquire()
        assert StemLock(str(tmp_path), "s").acquire(timeout=0) is False
    # A lock from another machine whose heartbeat stopped: stale after STALE_SECONDS of no change.
    monkeypatch.setattr(stemlock, "STALE_SECONDS", 0.3)
    with open(lock.path, "w") as fh:
        json.dump({"host": "elsewhere.example", "pid": 1, "token": "remote"}, fh)
    started = time.monotonic()
    with output_set(str(tmp_path), "s", lock_timeout=10) as staging:
        fake_set(staging, "y")
    assert 0.3 <= time.monotonic() - started < 5
    assert sorted(os.listdir(tmp_path)) == sorted(output_names("s"))


_WRITER = r"""
import os, random, sys, time
sys.path.insert(0, {repo!r})
from fracture_cli.io.outputs import output_names, output_set
out, tag, rounds = sys.argv[1], sys.argv[2], int(sys.argv[3])
for i in range(rounds):
    with output_set(out, "s") as staging:
        for name in output_names("s")[:-1]:
            with open(staging.file(name), "w") as fh:
                fh.write(f"{{tag}} {{i}} {{name}}\n" * random.randint(1, 400))
            time.sleep(random.random() * 0.002)
        staging.write_report({{"tag": tag, "round": i}})
"""


def test_concurrent_writers_never_leave_a_mixed_set(tmp_path):
    out = str(tmp_path / "out")
    os.mkdir(out)
    script = _WRITER.format(repo=REPO)
    writers = [subprocess.Popen([sys.executable, "-c", script, out, tag, "15"]) for tag in "abc"]
    seen = set()
    while any(w.poll() is None for w in writers):
        problem = verify_output_set(out, "s")
        if problem is None:  # a reader that checks the manifest only ever accepts whole sets
            seen.add(json.loads(open(os.path.join(out, "s.report.json")).read())["tag"])
        time.sleep(0.005)
    assert [w.returncode for w in writers] == [0, 0, 0]
    assert verify_output_set(out, "s") is None
    assert sorted(os.listdir(out)) == sorted(output_names("s"))
    assert seen <= set("abc")


_KILLED = r"""
import os, signal, sys
sys.path.insert(0, {repo!r})
from fracture_cli.io.outputs import output_names, output_set
out = sys.argv[1]
real, count = os.replace, [0]
def replace(src, dst, **kw):
    if ".staging-" in str(src) and os.path.dirname(str(dst)) == out:
        count[0] += 1
        if count[0] == 3:
            os.kill(os.getpid(), signal.SIGKILL)
    return real(src, dst, **kw)
os.replace = replace
with output_set(out, "s") as staging:
    for name in output_names("s")[:-1]:
        open(staging.file(name), "w").write("new " + name)
    staging.write_report({{"tag": "new"}})
"""


def test_sigkill_while_publishing_is_completed_by_the_next_run(tmp_path):
    out = str(tmp_path)
    with output_set(out, "s") as staging:
        fake_set(staging, "old")
    killed = subprocess.run([sys.executable, "-c", _KILLED.format(repo=REPO), out])
    assert killed.returncode == -signal.SIGKILL
    assert verify_output_set(out, "s") is not None  # mixed until the next run
    assert any(".staging-" in n for n in os.listdir(out)) and os.path.exists(StemLock(out, "s").path)
    preflight(out, "s")  # the next bake's first step
    assert verify_output_set(out, "s") is None
    assert json.loads((tmp_path / "s.report.json").read_text())["tag"] == "new"
    assert sorted(os.listdir(out)) == sorted(output_names("s"))


# ---------------------------------------------------------------- processes: concurrent, killed, interrupted


def fracture(*args) -> list[str]:
    return [sys.executable, "-m", "fracture_cli", *args]


@pytest.mark.usefixtures("previous")  # a warm cache: the two bakes skip the cage and modes
def test_two_concurrent_bakes_of_one_stem(asset, cache, tmp_path):
    out = str(tmp_path / "out")
    runs = [subprocess.Popen(fracture("bake", asset, "-o", out, "--cache", cache, *SMALL, *extra),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
            for extra in ([], NEW)]
    results = [r.communicate(timeout=600) for r in runs]
    assert [r.returncode for r in runs] == [0, 0], results
    assert verify_output_set(out, "box") is None
    assert sorted(os.listdir(out)) == sorted(output_names("box"))


def _wait_for_worker(pid: int, timeout: float = 120.0) -> None:
    """Until the bake's TetGen worker (a child of ``pid``) runs."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = subprocess.run(["pgrep", "-P", str(pid), "-f", "stages.tetra.tetgen"], capture_output=True)
        if found.stdout.strip():
            return
        time.sleep(0.05)
    pytest.fail("the TetGen worker did not start")


def _worker_dirs(pid: int) -> list[str]:
    import tempfile

    prefix = f"fracture-tetgen-{pid}-"
    return [n for n in os.listdir(tempfile.gettempdir()) if n.startswith(prefix)]


def _bake_in_tetgen(asset: str, out: str, sigint: signal.Handlers) -> subprocess.Popen:
    """A bake in a session of its own (SIGINT set to ``sigint``), once it runs its TetGen worker."""
    bake = subprocess.Popen(fracture("bake", asset, "-o", out, *SMALL), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=REPO, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, sigint))
    _wait_for_worker(bake.pid)
    return bake


def _assert_stopped_cleanly(bake: subprocess.Popen, out: str) -> None:
    """The bake ended as an interrupt does: exit 130, one line, nothing written, its TetGen worker's folder gone."""
    _, stderr = bake.communicate(timeout=60)
    assert bake.returncode == 130, stderr
    assert "Traceback" not in stderr and "Exception ignored" not in stderr, stderr
    assert "interrupted; no output was written (previous outputs are unchanged)" in stderr
    assert _worker_dirs(bake.pid) == []
    assert not os.path.exists(out) or os.listdir(out) == []


@pytest.mark.skipif(shutil.which("pgrep") is None, reason="needs pgrep (procps) to find the TetGen worker")
def test_double_ctrl_c_to_the_process_group_is_clean(asset, tmp_path):
    out = str(tmp_path / "out")
    bake = _bake_in_tetgen(asset, out, signal.SIG_DFL)
    os.killpg(bake.pid, signal.SIGINT)
    time.sleep(0.05)
    os.killpg(bake.pid, signal.SIGINT)
    _assert_stopped_cleanly(bake, out)


@pytest.mark.skipif(shutil.which("pgrep") is None, reason="needs pgrep (procps) to find the TetGen worker")
@pytest.mark.usefixtures("previous")  # a warm cache for the second bake
def test_sigkill_then_a_new_bake_cleans_up(asset, cache, tmp_path):
    out = str(tmp_path / "out")
    killed = subprocess.Popen(fracture("bake", asset, "-o", out, *SMALL), cwd=REPO, stderr=subprocess.DEVNULL,
                              start_new_session=True)
    _wait_for_worker(killed.pid)
    os.makedirs(out, exist_ok=True)
    os.mkdir(os.path.join(out, ".box.staging-" + "f" * 32))  # as if killed while writing its files
    os.killpg(killed.pid, signal.SIGKILL)
    killed.wait()
    assert _worker_dirs(killed.pid), "the killed bake should have left its worker folder"
    result = subprocess.run(fracture("bake", asset, "-o", out, "--cache", cache, *SMALL), capture_output=True,
                            text=True, cwd=REPO)
    assert result.returncode == 0, result.stderr
    assert verify_output_set(out, "box") is None
    assert sorted(os.listdir(out)) == sorted(output_names("box"))
    # The worker folder is cleaned when the next bake starts its worker (not with --cache hits: that skips TetGen).
    from fracture_cli.stages.tetra.tetgen import clean_stale_workdirs

    clean_stale_workdirs()
    assert _worker_dirs(killed.pid) == []


def test_worker_folders_of_live_processes_are_kept(tmp_path):
    from fracture_cli.stages.tetra.tetgen import clean_stale_workdirs

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    stale = tmp_path / f"fracture-tetgen-{int(dead.stdout)}-x1y2z3"
    live = tmp_path / f"fracture-tetgen-{os.getpid()}-abc"
    unrelated = tmp_path / "fracture-tetgen-notes"
    for folder in (stale, live, unrelated):
        folder.mkdir()
    assert clean_stale_workdirs(str(tmp_path)) == [str(stale)]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([live.name, unrelated.name])


def test_numpy_is_not_needed_by_the_protocol():
    code = ("import sys, fracture_cli.io.outputs; "
            "print(sorted(m for m in ('numpy', 'trimesh', 'scipy') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO)
    assert out.stdout.strip() == "[]"
    assert np is not None


def test_chain_save_and_export_never_replace_their_input(tmp_path):
    glb = tmp_path / "prop.glb"
    shutil.copy(os.path.join(HERE, "data", "bad", "two_materials.glb"), glb)
    original = glb.read_bytes()
    result = CliRunner().invoke(cli, ["load", str(glb), "save", str(glb)])
    assert result.exit_code == 1
    assert_one_line(result, "prop.glb", "which this command reads")
    from fracture_cli.pipeline import PipelineState
    from fracture_cli.pipeline.bake import write_outputs
    from fracture_cli.pipeline.runner import Runner

    with pytest.raises(OutputError, match="which this command reads"):  # the chain's `export` step
        write_outputs(str(tmp_path), "prop", PipelineState(source=str(glb)), {}, Runner("t"))
    assert glb.read_bytes() == original and os.listdir(tmp_path) == ["prop.glb"]


@pytest.mark.skipif(shutil.which("pgrep") is None, reason="needs pgrep (procps) to find the TetGen worker")
def test_sigterm_stops_a_bake_as_ctrl_c_does(asset, tmp_path):
    """A build tool's SIGTERM (a timeout, make stopping a job) to the bake process alone: the same clean exit as
    Ctrl-C (exit 130, one line, no output written, the worker's folder gone), even with SIGINT ignored as in a
    background job."""
    out = str(tmp_path / "out")
    bake = _bake_in_tetgen(asset, out, signal.SIG_IGN)
    os.kill(bake.pid, signal.SIGTERM)
    _assert_stopped_cleanly(bake, out)
