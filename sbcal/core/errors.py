"""The one exception type for bad user input.

Every reader and validator raises :class:`InputError` with a one-line message that names
the file, the line or key, and the problem; the CLI prints it and exits with status 2.
"""

__all__ = ["InputError", "InputWarning"]


class InputError(ValueError):
    """Bad user input (file, option or parameter); the message is one line."""


class InputWarning(UserWarning):
    """Input that is read but is probably not what its writer meant (an unknown key one letter from a known
    one); the CLI prints it as one ``sbcal: warning:`` line and goes on."""
