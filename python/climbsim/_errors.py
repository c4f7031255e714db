"""climbsim's errors, as Python exceptions."""

from __future__ import annotations

from typing import Optional, Sequence


class ClimbsimError(RuntimeError):
    """climbsim refused or could not do what was asked: bad input (a scenario's unknown key, a
    missing file), a run interrupted, a server that did not start.

    The message is climbsim's own (its `climbsim: …` lines, and for `check` the scenario's
    error lines); `exit_code`, `command` and the whole `output` (stdout) and `errors` (stderr)
    are kept for the curious.
    """

    def __init__(
        self,
        message: str,
        *,
        exit_code: Optional[int] = None,
        command: Sequence[str] = (),
        output: str = "",
        errors: str = "",
    ) -> None:
        super().__init__(message)
        self.message = message
        self.exit_code = exit_code
        self.command = list(command)
        self.output = output
        self.errors = errors
