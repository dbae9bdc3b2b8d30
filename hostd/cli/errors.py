"""Exit codes and the one error type every hostctl verb raises for a user-facing failure."""

from __future__ import annotations

EXIT_OK = 0
EXIT_FAILED = 1  # the operation ran and failed (job failed, replay check refused, ...)
EXIT_USAGE = 2  # bad arguments, bad input file, bad config
EXIT_UNREACHABLE = 3  # the daemon's control socket cannot be reached
EXIT_REFUSED = 4  # the daemon answered with an error
EXIT_INTERRUPTED = 130  # Ctrl-C (128 + SIGINT)
EXIT_PIPE = 141  # the reader of stdout went away (hostctl ... | head): 128 + SIGPIPE, quietly


class CliError(Exception):
    """A failure reported as one line on stderr with ``code`` as the exit status."""

    def __init__(self, message: str, code: int = EXIT_USAGE) -> None:
        super().__init__(message)
        self.code = code
