"""Exceptions with a meaning the Rust side acts on.

:class:`InputError` marks a problem with what the user passed (unknown task, a trajectory
that leaves the workspace, an existing output directory). The bridge turns it into a
bad-input error (exit code 2) with its message; any other exception is a runtime failure.
:class:`NotGrounded` is the input error of a prompt whose objects cannot fill a model's
slots (the HTTP API answers it with 422 rather than 400).
"""


class InputError(ValueError):
    """The caller's input is wrong; the message says what and how to fix it."""


class NotGrounded(InputError):
    """The prompt cannot drive the model: a role the model needs is missing from the prompt,
    its object was not found in the image, or the model's task has no roles on record."""
