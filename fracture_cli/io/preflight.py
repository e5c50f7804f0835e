"""Checks before any long work: can the outputs be written, and would they spare every input?

:func:`preflight` checks a bake's output folder; :func:`guard_outputs` is the
one output guard every command that writes calls first: no output may be, or
lead to, a file the command reads, nor replace a file of a published bake set
other than by republishing that set. Each failure is one
:class:`~fracture_cli.errors.OutputError` line naming the paths (docs/OUTPUTS.md,
"What is refused before any work").
"""

from __future__ import annotations

import errno
import json
import os
import secrets
from collections.abc import Iterable
from dataclasses import dataclass

from fracture_cli.errors import OutputError, printable
from fracture_cli.io.diskspace import free_bytes, human_size
from fracture_cli.io.outputs import REPORT_SUFFIX, all_names, recover, write_error
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
    try:  # released whatever happens (a Ctrl-C right after acquire included); only our own lock is removed
        if lock.acquire(timeout=0):
            recover(out_dir, stem)
    except OSError as exc:
        raise write_error(exc, out_dir) from None
    finally:
        lock.release()


def check_folder_path(out_dir: str) -> None:
    """Refuse a folder path no folder can be made at: a file, a dangling symbolic link or a link loop (on the way).

    Raises
    ------
    OutputError
        One line naming ``out_dir`` and what is in the way.
    """
    if not os.path.isdir(out_dir):
        _existing_ancestor(out_dir)


def _existing_ancestor(out_dir: str) -> str:
    """The nearest existing folder above a missing ``out_dir`` (refused if a file is in the way)."""
    path = os.path.abspath(out_dir)
    while not os.path.exists(path):
        if os.path.lexists(path):  # a symlink that leads nowhere: makedirs would fail with "File exists" at the end
            _refuse_broken_link(path, out_dir)
        parent = os.path.dirname(path)
        if parent == path:
            break
        path = parent
    if not os.path.isdir(path):
        what = "the output folder is a file, not a folder" if path == os.path.abspath(out_dir) else \
            f"cannot create the output folder: {printable(path)} is a file"
        raise OutputError(what, path=printable(out_dir))
    return path


def _refuse_broken_link(link: str, out_dir: str) -> None:
    """Refuse an output folder that is, or is inside, a dangling symbolic link or a symbolic link loop."""
    try:
        os.stat(link)
        kind = "a symbolic link that cannot be followed"
    except OSError as exc:
        kind = "a symbolic link loop" if exc.errno == errno.ELOOP else \
            f"a dangling symbolic link (to {printable(os.readlink(link))}, which does not exist)"
    where = "the output folder is" if link == os.path.abspath(out_dir) else \
        f"cannot create the output folder: {printable(link)} is"
    raise OutputError(f"{where} {kind}; give a folder, or fix the link", path=printable(out_dir))


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


def _check_free_space(folder: str, stem: str, estimate_bytes: int, out_dir: str) -> None:
    free = free_bytes(folder)
    if estimate_bytes > free:
        raise OutputError(f"only {human_size(free)} free in the output folder; the outputs of {printable(stem)} need "
                          f"about {human_size(estimate_bytes)}", path=printable(out_dir))


def check_inputs_untouched(out_dir: str, stems: Iterable[str], inputs: Iterable[str]) -> None:
    """Refuse if an output of the bake sets ``stems`` in ``out_dir`` would replace one of ``inputs``.

    Raises
    ------
    OutputError
        See :func:`guard_outputs` (published bake sets are checked too).
    """
    guard_outputs(inputs=inputs, sets=[(out_dir, stem) for stem in stems])


# ----------------------------------------------------------------------------
# The output guard: every command that writes calls it before any work


@dataclass(frozen=True)
class _File:
    """A path as the guard compares it: as given, resolved (symlinks followed), and its inode if it exists."""

    path: str
    real: str
    inode: tuple[int, int] | None

    @classmethod
    def of(cls, path: str) -> _File:
        try:
            st = os.stat(path)
            inode: tuple[int, int] | None = (st.st_dev, st.st_ino)
        except (OSError, ValueError):  # missing, dangling link, a name with NUL
            inode = None
        return cls(path, os.path.realpath(path), inode)

    def same(self, other: _File) -> bool:
        """Whether writing one replaces the other: the same resolved path, or the same existing file (a hard link)."""
        return self.real == other.real or (self.inode is not None and self.inode == other.inode)

    def relation(self, other: _File) -> str:
        """How ``self`` reaches ``other``, for the message ("" when they are the same path)."""
        if os.path.normpath(os.path.abspath(self.path)) == os.path.normpath(os.path.abspath(other.path)):
            return ""
        if self.real == other.real:
            return f" ({printable(self.path)} leads to it through a symbolic link)"
        return f" ({printable(self.path)} is a hard link to it)"


@dataclass(frozen=True)
class PublishedSet:
    """A bake set published in a folder: its report (the manifest) and every file the report lists."""

    report: str
    folder: str  # resolved
    stem: str
    members: tuple[_File, ...]


def published_sets(folder: str) -> tuple[PublishedSet, ...]:
    """The bake sets published in ``folder``: each ``<stem>.report.json`` with a ``"files"`` table.

    A set's members are its report and the files its ``"files"`` lists
    (docs/OUTPUTS.md); reports that are not JSON objects with that table are
    not sets. A folder that cannot be listed has none.
    """
    try:
        names = sorted(n for n in os.listdir(folder or ".") if n.endswith(REPORT_SUFFIX) and n != REPORT_SUFFIX)
    except OSError:
        return ()
    found = []
    for name in names:
        report = os.path.join(folder, name)
        files = _report_files(report)
        if files is None:
            continue
        listed = [n for n in files if isinstance(n, str) and n and "\0" not in n]
        members = (_File.of(report),) + tuple(_File.of(os.path.join(folder, n)) for n in listed)
        found.append(PublishedSet(report, os.path.realpath(folder), name[: -len(REPORT_SUFFIX)], members))
    return tuple(found)


def _report_files(path: str) -> dict | None:
    """The ``"files"`` table of a report, or None when ``path`` is not a bake report (or is huge, or unreadable)."""
    try:
        if not os.path.isfile(path) or os.path.getsize(path) > _MAX_REPORT_BYTES:
            return None
        with open(path, encoding="utf-8") as fh:
            files = json.load(fh).get("files")
    except (OSError, ValueError, AttributeError):
        return None
    return files if isinstance(files, dict) else None


_MAX_REPORT_BYTES = 64 << 20  # a bake's report is tens of KiB; a bigger *.report.json is something else


def guard_outputs(outputs: Iterable[str] = (), inputs: Iterable[str] = (), *,
                  sets: Iterable[tuple[str, str]] = ()) -> None:
    """Refuse, before any work, to write a file the command reads or a file of a published bake set.

    The one guard of every command that writes (bake, batch, the chain's
    ``save``, ``save-cage``, ``save-tets`` and ``export``, ``impact -o`` and
    ``--png``, ``preview -o``). An output may not be, or lead to, an input:
    paths are compared resolved (symlinks, symlinked folders) and existing files
    by device and inode (hard links). Nor may it replace a file of a bake set
    published in its folder (the report and every file its ``"files"`` lists)
    unless it is that set's own file being republished: a bake of that stem
    into that folder (``sets``).

    Parameters
    ----------
    outputs : iterable of str
        Files the command writes on their own.
    inputs : iterable of str
        Every file the command reads: the assets and their companion files
        (:func:`~fracture_cli.io.inputs.input_files`), a runtime file and its
        ``.bin``, the GLB and report read beside it.
    sets : iterable of (str, str)
        ``(folder, stem)`` of every bake set the command publishes; each name
        of :func:`~fracture_cli.io.outputs.all_names` in ``folder`` is an output.

    Raises
    ------
    OutputError
        One line naming the output and the file it would replace; nothing is written.
    """
    targets: list[tuple[str, tuple[str, str] | None]] = [(path, None) for path in outputs]
    for folder, stem in sets:
        targets += [(os.path.join(folder, name), (os.path.realpath(folder), stem)) for name in all_names(stem)]
    read = [_File.of(path) for path in dict.fromkeys(inputs)]
    seen: list[_File] = []
    folders: dict[str, tuple[PublishedSet, ...]] = {}
    for path, republishes in targets:
        target = _File.of(path)
        for other in read:
            if target.same(other):
                raise OutputError(f"the output would replace {printable(other.path)}, which this command reads"
                                  f"{target.relation(other)}; write the output elsewhere", path=printable(path))
        for other in seen:
            if target.same(other):
                raise OutputError(f"two outputs of this command are the same file ({printable(other.path)}); give "
                                  "each its own name", path=printable(path))
        seen.append(target)
        for folder in dict.fromkeys((os.path.dirname(os.path.abspath(path)), os.path.dirname(target.real))):
            if folder not in folders:
                folders[folder] = published_sets(folder)
            for published in folders[folder]:
                if republishes == (published.folder, published.stem):
                    continue
                for member in published.members:
                    if target.same(member):
                        raise OutputError(
                            f"the output would replace {printable(member.path)}, a file of the bake set "
                            f"{printable(published.report)} lists{target.relation(member)}; only a bake of "
                            f"{printable(published.stem)} into that folder replaces it: write the output elsewhere",
                            path=printable(path))
