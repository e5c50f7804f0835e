"""Checks before a bake's long work: can its outputs be written, and would they spare every input?

Each failure is one :class:`~fracture_cli.errors.OutputError` line naming the
folder or file (docs/OUTPUTS.md, "What is refused before any work").
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
from collections.abc import Iterable

from fracture_cli.errors import OutputError, printable
from fracture_cli.io.outputs import all_names, recover, write_error
from fracture_cli.io.stemlock import StemLock


def preflight(out_dir: str, stem: str, inputs: Iterable[str] = (), estimate_bytes: int = 0) -> None:
    """Check, before any long work, that ``stem``'s outputs can be written into ``out_dir``.

    Parameters
    ----------
    out_dir : str
        Output folder; if missing, its nearest existing parent is checked
        instead and the folder is made by :func:`output_set`, so a bake that
        fails before writing leaves no empty folder behind.
    stem : str
        The outputs' base name.
    inputs : iterable of str, optional
        Every file the batch reads (assets and their companion files): none
        may be an output path.
    estimate_bytes : int, optional (default 0)
        Expected size of the outputs; refused when the folder has less free space.

    Raises
    ------
    OutputError
        One line naming the folder or file and the problem.
    """
    if not out_dir:
        raise OutputError('the output folder is "" (empty); give one, e.g. -o build/out')
    try:
        os.fsencode(stem).decode("utf-8")
    except UnicodeDecodeError:
        raise OutputError(f"the file name is not valid UTF-8 ({printable(stem)}): the outputs and the runtime "
                          "file's reference to its .bin need a UTF-8 name; rename the input") from None
    if not os.path.isdir(out_dir):
        # Created only when the outputs are written, so a bake that fails leaves no empty folder behind.
        ancestor = _existing_ancestor(out_dir)
        _check_writable(ancestor, for_new_folder=True)
        _check_free_space(ancestor, stem, estimate_bytes, out_dir)
        return
    for name in all_names(stem):
        target = os.path.join(out_dir, name)
        if os.path.lexists(target) and not os.path.isfile(target):
            raise OutputError("is in the way of an output (not a regular file); remove or rename it",
                              path=printable(target))
    check_inputs_untouched(out_dir, [stem], inputs)
    _check_writable(out_dir)
    _check_free_space(out_dir, stem, estimate_bytes, out_dir)
    # Complete or clear what a killed bake left now, so the folder holds one set even if this bake fails.
    lock = StemLock(out_dir, stem)
    if lock.acquire(timeout=0):
        try:
            recover(out_dir, stem)
        except OSError as exc:
            raise write_error(exc, out_dir) from None
        finally:
            lock.release()


def _existing_ancestor(out_dir: str) -> str:
    """The nearest existing folder above a missing ``out_dir`` (refused if a file is in the way)."""
    path = os.path.abspath(out_dir)
    while not os.path.exists(path):
        parent = os.path.dirname(path)
        if parent == path:
            break
        path = parent
    if not os.path.isdir(path):
        what = "the output folder is a file, not a folder" if path == os.path.abspath(out_dir) else \
            f"cannot create the output folder: {printable(path)} is a file"
        raise OutputError(what, path=printable(out_dir))
    return path


def _check_writable(folder: str, *, for_new_folder: bool = False) -> None:
    """Create and remove a probe in ``folder`` (a file, or a folder when the output folder is still to be made)."""
    probe = os.path.join(folder, f".fracture-probe-{secrets.token_hex(8)}")
    try:
        if for_new_folder:
            os.mkdir(probe, 0o700)
            os.rmdir(probe)
        else:
            os.close(os.open(probe, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
            os.unlink(probe)
    except OSError as exc:
        what = "cannot create the output folder" if for_new_folder else "the output folder is not writable"
        raise OutputError(f"{what} ({exc.strerror})", path=printable(folder)) from None


def free_bytes(out_dir: str) -> int:
    """Bytes available to this user in ``out_dir``'s file system."""
    return shutil.disk_usage(out_dir).free


def _check_free_space(folder: str, stem: str, estimate_bytes: int, out_dir: str) -> None:
    free = free_bytes(folder)
    if estimate_bytes > free:
        raise OutputError(f"only {human_size(free)} free in the output folder; the outputs of {printable(stem)} need "
                          f"about {human_size(estimate_bytes)}", path=printable(out_dir))


def human_size(n: float) -> str:
    for unit in ("bytes", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} TiB"  # pragma: no cover


def check_inputs_untouched(out_dir: str, stems: Iterable[str], inputs: Iterable[str]) -> None:
    """Refuse if an output path of any of ``stems`` in ``out_dir`` is one of ``inputs``.

    Raises
    ------
    OutputError
        See :func:`refuse_replacing_inputs`.
    """
    refuse_replacing_inputs([os.path.join(out_dir, name) for stem in stems for name in all_names(stem)], inputs)


def refuse_replacing_inputs(targets: Iterable[str], inputs: Iterable[str]) -> None:
    """Refuse if a file about to be written (``targets``) is one of ``inputs``.

    Real paths are compared (:func:`os.path.samefile`: the same device and
    inode), so an input reached through a symlink, a symlinked folder or a
    hard link is found too. Targets that do not exist yet are fine.

    Raises
    ------
    OutputError
        Naming the input and the output that would replace it.
    """
    existing = []
    for path in inputs:
        with contextlib.suppress(OSError):
            existing.append((path, os.stat(path)))
    for target in targets:
        try:
            st = os.stat(target)
        except OSError:
            continue
        for path, ist in existing:
            if (st.st_dev, st.st_ino) == (ist.st_dev, ist.st_ino):
                raise OutputError(f"is an input of this bake and the output {printable(target)} would replace "
                                  "it; write into another folder", path=printable(path))


def refuse_inputs_as_outputs(out_dir: str, inputs: Iterable[str]) -> None:
    """Refuse a batch in which an output path of one input is another input (or a companion file of one).

    Raises
    ------
    OutputError
        See :func:`check_inputs_untouched`.
    """
    from fracture_cli.io.inputs import input_files

    if not out_dir:
        return  # preflight() says what is wrong with it
    inputs = list(inputs)
    stems = [os.path.splitext(os.path.basename(p))[0] for p in inputs]
    check_inputs_untouched(out_dir, stems, [f for p in inputs for f in input_files(p)])
