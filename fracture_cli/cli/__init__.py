"""The ``fracture`` console script: :func:`main`, which installs the Ctrl-C handling before the rest loads.

The click group and its commands live in :mod:`fracture_cli.cli.group`; every
name of it is reachable from here too (``from fracture_cli.cli import cli``),
imported on first use. This module imports only the standard library and the
package itself, so a Ctrl-C while the tool starts (imports take a tenth of a
second, a bake's native libraries seconds more) is reported as an interrupt,
exit code 130, and never as an internal error.
"""

from __future__ import annotations

import atexit
import logging
import os
import signal
import sys
import threading

from fracture_cli.system import interrupts

TYPE_CHECKING = False  # not typing's: importing typing costs start-up time before Ctrl-C is handled
if TYPE_CHECKING:
    from typing import Any


def _terminated(signum: int, frame: Any) -> None:
    """SIGTERM (a build tool or a timeout stopping the bake) ends it as Ctrl-C does: through the SIGINT handler
    in place (the output set is finished or left as it was, temporary files go, make's job tokens go back)."""
    handler = signal.getsignal(signal.SIGINT)
    if callable(handler):
        handler(signal.SIGINT, frame)
    else:  # SIGINT ignored (started in the background) or not set from Python: SIGTERM still stops the bake
        interrupts.record(signum)
        raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> None:
    """Entry point of the ``fracture`` console script."""
    interrupts.forget()
    interrupts.install()
    if signal.getsignal(signal.SIGTERM) == signal.SIG_DFL:
        signal.signal(signal.SIGTERM, _terminated)
    try:
        try:
            # on first use: keeps `fracture` start-up light
            from fracture_cli.cli.commands import cli
        except BaseException as exc:  # noqa: BLE001  (an interrupt while the tool loads: any exception it became)
            if isinstance(exc, SystemExit) or not interrupts.caused_by_interrupt(exc):
                raise
            sys.stderr.write(f"fracture: {interrupts.NOTHING_WRITTEN}\n")
            raise SystemExit(interrupts.EXIT_INTERRUPTED) from None
        raise SystemExit(_run(cli, argv))
    except SystemExit:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # exiting: a second Ctrl-C must not break the clean exit
        signal.signal(signal.SIGTERM, signal.SIG_DFL)  # and a SIGTERM now just ends the process
        raise


def _run(cli: Any, argv: list[str] | None) -> int:
    """Run the click group (not in click's standalone mode, so every way it can end is decided here); the exit code.

    Inside a command the group itself maps errors to one line and an exit code
    (:class:`fracture_cli.cli.group.FractureGroup`); here are the rest: click's
    usage errors, and a Ctrl-C or a closed stdout outside any command, which
    click would report as "Aborted!" or a broken pipe with exit code 1.
    """
    # on first use: keeps `fracture` start-up light
    import click

    from fracture_cli.cli.group import quiet_broken_pipe, stdout_closed
    from fracture_cli.io.outputs import interrupt_message

    try:
        code = cli.main(args=argv, prog_name="fracture", standalone_mode=False)
    except (KeyboardInterrupt, click.exceptions.Abort) as exc:
        if not interrupts.caused_by_interrupt(exc):  # click's own Abort (a prompt's end of input)
            click.echo("Aborted!", err=True)
            return 1
        click.echo(f"fracture: {interrupt_message()}", err=True)
        return interrupts.EXIT_INTERRUPTED
    except click.ClickException as exc:
        exc.show()
        return exc.exit_code
    except BrokenPipeError:
        if not stdout_closed():
            raise
        return quiet_broken_pipe()
    code = code if isinstance(code, int) else 0
    if code == 0 and interrupts.received():
        # A Ctrl-C the command did not stop for (held back past its last step, or dropped by a library after
        # the last checkpoint): it still came, so the run ends as interrupted, saying what was published.
        click.echo(f"fracture: {interrupt_message()}", err=True)
        return interrupts.EXIT_INTERRUPTED
    return code


def console() -> None:
    """The ``fracture`` console script: :func:`main`, then an exit that skips the interpreter's teardown.

    Once the command has finished (outputs published, streams flushed, the
    ``atexit`` handlers run: worker pools, locks, temporary files), freeing
    every module's objects one by one only costs time: 0.4 s after a bake
    (numba, llvmlite, open3d and a few hundred MB of arrays), 6-7% of a small
    bake's wall time (issue 33). With another thread still running (none
    should be; the progress clock is a daemon) the normal exit waits for it.
    """
    try:
        main()
        code: object = 0
    except SystemExit as exc:
        code = exc.code
    if any(t.is_alive() and not t.daemon for t in threading.enumerate() if t is not threading.main_thread()):
        raise SystemExit(code)
    if code is None:
        status = 0
    elif isinstance(code, int):
        status = code
    else:  # SystemExit("message"): printed, status 1, as the interpreter would
        sys.stderr.write(f"{code}\n")
        status = 1
    logging.shutdown()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed or broken stream: the interpreter's exit status for it
            status = status or 120
    os._exit(status)


_SUBMODULES = frozenset({"atlas", "batch", "commands", "group", "options", "tools"})


def __getattr__(name: str) -> Any:
    """The click group's names (``cli``, ``Chain``, ``EXAMPLES`` ...), from :mod:`fracture_cli.cli.group`."""
    if name.startswith("__") or name in _SUBMODULES:
        raise AttributeError(name)  # a submodule: let the import system load it
    from fracture_cli.cli import commands  # noqa: F401  (registers every command on the group)
    from fracture_cli.cli import group as cli_group

    try:
        return getattr(cli_group, name)
    except AttributeError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None


__all__ = ["console", "main"]

if __name__ == "__main__":
    console()
