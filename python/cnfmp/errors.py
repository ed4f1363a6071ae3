"""Exceptions with a meaning the Rust side acts on.

:class:`InputError` marks a problem with what the user passed (unknown task, a trajectory
that leaves the workspace, an existing output directory). The bridge turns it into a
bad-input error (exit code 2) with its message; any other exception is a runtime failure.
"""


class InputError(ValueError):
    """The caller's input is wrong; the message says what and how to fix it."""
