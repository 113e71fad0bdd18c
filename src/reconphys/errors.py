"""User-facing errors: one line that names the input and says what was expected."""

from __future__ import annotations


class InputError(ValueError):
    """Bad user input (missing/corrupt file, wrong shape or dtype, NaN, out-of-range value).

    The CLI prints ``error: <message>`` on one line and exits with status 2, without a traceback.
    ``source`` names the file (or argument) and ``field`` the entry inside it, when known.
    """

    def __init__(self, message: str, source: str | None = None, field: str | None = None):
        self.source = source
        self.field = field
        where = ""
        if source is not None:
            where = f"{source}" + (f" [{field}]" if field else "") + ": "
        elif field is not None:
            where = f"{field}: "
        super().__init__(where + message)
