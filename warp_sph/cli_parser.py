"""argparse with one-line errors: the parser of every ``warp-sph`` command and of ``warp-sph bench``
(``warp_sph.cli`` and ``benchmarks/runner.py`` both import it; it imports neither).
"""
from __future__ import annotations

import argparse
import re

from .core.errors import WarpSphError


class _AllCores:
    """``--workers`` given without N: one worker per core (a non-string const, which argparse does not
    convert, so that an explicit 0 stays distinguishable and is refused)."""

    def __repr__(self):
        return "ALL_CORES"


ALL_CORES = _AllCores()


class UsageError(WarpSphError):
    """A command line argparse refused: ``main`` prints it as one line, exit status 2."""


class OneLineParser(argparse.ArgumentParser):
    """argparse, its errors one line (``warp-sph: error: plan: argument --budget: ...``) instead of the usage
    block; subcommands' parsers are of the same class (``warp-sph bench``'s too)."""

    def error(self, message):
        m = re.match(r"argument (?:\S+/)?(-\S+): expected one argument$", message)
        if m:  # argparse takes a value such as -5s for an option
            message += f" (a value that starts with '-' is written {m.group(1)}=VALUE)"
        cmd = self.prog.split(" ", 1)[1] + ": " if " " in self.prog else ""
        raise UsageError(f"{cmd}{message}; see {self.prog} --help")

    def parse_args(self, args=None, namespace=None):
        """As argparse's, an unknown argument named with its command (``run: unrecognized arguments: ...``)."""
        parsed, extra = self.parse_known_args(args, namespace)
        if extra:
            cmd = getattr(parsed, "command", None)
            prog = f"{self.prog} {cmd}" if cmd else self.prog
            where = prog.split(" ", 1)[1] + ": " if " " in prog else ""
            raise UsageError(f"{where}unrecognized arguments: {' '.join(extra)}; see {prog} --help")
        return parsed


def short_usage(parser: argparse.ArgumentParser) -> str:
    """What a command run without its subcommand prints (``warp-sph``, ``warp-sph bench``; on stderr, exit
    status 2, a usage error): the usage line, each subcommand with its one-line help, and where the full help is."""
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    helps = [(c.dest, c.help or "") for c in sub._choices_actions]
    width = max(len(name) for name, _ in helps)
    flags = "".join(f" [{a.option_strings[0]}]" for a in parser._actions
                    if a.option_strings and a.nargs == 0 and a.dest != "help")
    lines = [f"usage: {parser.prog}{flags} COMMAND [ARGS]", "commands:"]
    lines += [f"  {name:<{width}}  {text}" for name, text in helps]
    head, _, cmd = parser.prog.partition(" ")  # "warp-sph: error: bench: ...", as OneLineParser's errors
    lines.append(f"{head}: error: {cmd + ': ' if cmd else ''}no command given; see {parser.prog} --help, or "
                 f"{parser.prog} COMMAND --help")
    return "\n".join(lines)
