"""argparse with one-line errors: the parser of every ``warp-sph`` command and of ``warp-sph bench``
(``warp_sph.cli`` and ``benchmarks/runner.py`` both import it; it imports neither).
"""
from __future__ import annotations

import argparse
import re

from .core.errors import WarpSphError


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
