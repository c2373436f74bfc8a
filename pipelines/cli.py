"""The ``wrinkles`` command line.

Each sub-command lives in its own module with ``HELP``, ``DESCRIPTION``,
``add_arguments(parser)`` and ``run(args)``; ``COMMANDS`` is the registry (STYLE.md 5: explicit
registries, no import-by-string from user input). The commands import their shared options from
``pipelines.options``, never this module. User errors (``WrinklesInputError``) print one line and
exit with status 2; SIGTERM and Ctrl-C unwind the job (``pipelines.interrupts``).
"""

from __future__ import annotations

import argparse
import io
import os
import sys
import textwrap

from pipelines import (
    animate_cmd,
    body_cmd,
    dataset_cmd,
    evaluate_cmd,
    garments_cmd,
    motions_cmd,
    simulate_cmd,
    train_cmd,
)
from pipelines.interrupts import interruption, restore_sigterm, terminate_as_interrupt
from pipelines.options import join_negative_values
from pipelines.progress import quiet_progress
from sim import __version__
from sim.errors import WrinklesInputError

EXIT_USAGE = 2


COMMANDS = {
    "body": body_cmd,
    "motions": motions_cmd,
    "garments": garments_cmd,
    "simulate": simulate_cmd,
    "dataset": dataset_cmd,
    "train": train_cmd,
    "evaluate": evaluate_cmd,
    "animate": animate_cmd,
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="wrinkles",
        description=textwrap.dedent("""\
            wrinkles: garment animation with realistic wrinkles.
            Warp cloth simulation on SMPL-convention bodies, learned wrinkle models, USD out.
            Units are SI (metres, seconds, kilograms), Y is up."""),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Run 'wrinkles COMMAND --help' for the options of a command.",
    )
    parser.add_argument("--version", action="version", version=f"wrinkles {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, mod in COMMANDS.items():
        p = sub.add_parser(name, help=mod.HELP, description=mod.DESCRIPTION,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(join_negative_values(sys.argv[1:] if argv is None else list(argv)))
    if not getattr(args, "command", None):
        parser.print_help()
        return EXIT_USAGE
    previous = terminate_as_interrupt()
    try:
        with quiet_progress(getattr(args, "quiet", False)):  # also the bars of library code
            code = int(args._run(args) or 0)
        sys.stdout.flush()  # here, where a closed pipe is caught, not at the interpreter's exit
        return code
    except WrinklesInputError as e:
        print(f"wrinkles {args.command}: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt as e:
        how, code = interruption(e)
        print(f"wrinkles {args.command}: {how}; no output was written", file=sys.stderr)
        return code
    except BrokenPipeError:  # `wrinkles garments | head`: the reader left; say nothing more
        if not _stdout_closed():
            raise  # another pipe (a socket, a subprocess): a real error
        try:  # and let the interpreter's last flush of stdout go nowhere
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
            os.close(devnull)
        except (OSError, ValueError, io.UnsupportedOperation):
            pass
        return 141
    finally:
        restore_sigterm(previous)


def _stdout_closed() -> bool:
    """Whether standard output is a pipe whose reader has gone (poll reports an error on it);
    True where that cannot be told (no file descriptor: captured output)."""
    import select

    try:
        fd = sys.stdout.fileno()
    except (OSError, ValueError, io.UnsupportedOperation):
        return True
    poll = select.poll()
    poll.register(fd, select.POLLOUT)
    return any(ev & (select.POLLERR | select.POLLHUP) for _, ev in poll.poll(0))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
