"""The ``mmwsim`` console script.

Each subcommand lives in its own module with ``register(subparsers)``; modules
import their heavy dependencies (torch, ompl) inside the command, so that
scene-to-data-set work never loads torch. User mistakes print one line and exit 2.

Exit status: 0 success, 2 bad input (one line on stderr), 3 no solution found
(``mmwsim plan``), 130 interrupted.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings

from ..errors import MmwsimError

__all__ = ["main", "build_parser", "check_threads", "EXIT_USAGE", "EXIT_NO_SOLUTION"]

EXIT_USAGE = 2
EXIT_NO_SOLUTION = 3
MAX_THREADS = 1024  # torch crashes (segfault) when asked for some 100000 threads

# Subcommand modules, in help order; a module missing here is simply not offered.
COMMANDS = (
    "mmwsim.cli.scene",
    "mmwsim.cli.trace",
    "mmwsim.cli.generate",
    "mmwsim.cli.trajectories",
    "mmwsim.cli.train",
    "mmwsim.cli.refit",
    "mmwsim.cli.evaluate",
    "mmwsim.cli.plan",
    "mmwsim.cli.demo",
)


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2
        self.exit(EXIT_USAGE, f"mmwsim: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    from ..version import __version__

    parser = _Parser(prog="mmwsim", description="28 GHz mmWave simulation over 3D city meshes.")
    parser.add_argument("--version", action="version", version=f"mmwsim {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for name in COMMANDS:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as e:
            if e.name == name:
                continue
            raise
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    warnings.simplefilter("default")
    try:
        status = args.func(args)
    except MmwsimError as e:
        print(f"mmwsim: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("mmwsim: interrupted", file=sys.stderr)
        return 130
    return int(status or 0)


def parse_vector(text: str, n: int, what: str) -> tuple[float, ...]:
    """``"1,2,3"`` -> (1.0, 2.0, 3.0) with ``n`` finite numbers, else a one-line error."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise MmwsimError(f"{what} {text!r}: expected {n} comma-separated numbers") from None
    if len(values) != n or not all(v == v and abs(v) != float("inf") for v in values):
        raise MmwsimError(f"{what} {text!r}: expected {n} finite comma-separated numbers")
    return values


def check_threads(n: int) -> int:
    """``--threads N``: 1..1024, else a one-line error."""
    if not 1 <= n <= MAX_THREADS:
        raise MmwsimError(f"--threads must be from 1 to {MAX_THREADS}, got {n}")
    return n
