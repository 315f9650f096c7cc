"""The one exception type for bad user input.

Every reader and validator raises :class:`InputError` with a one-line message that names
the file, the line or key, and the problem; the CLI prints it and exits with status 2.
"""

__all__ = ["InputError"]


class InputError(ValueError):
    """Bad user input (file, option or parameter); the message is one line."""
