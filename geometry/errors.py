"""The one exception type for bad input that a person can fix.

Every layer raises it (or a subclass) with a message that names the file, key or value and says what to do;
the CLI prints that message on one line and exits with status 2 instead of showing a traceback.
"""


class InputError(Exception):
    """Bad input a person can fix: the message names what is wrong and what to do next."""

    def __init__(self, message: str, hint: str | None = None) -> None:
        self.message = message
        self.hint = hint
        super().__init__(message if hint is None else f"{message} — {hint}")
