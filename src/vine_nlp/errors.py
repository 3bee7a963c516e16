"""Errors shared by every layer."""


def printable(text) -> str:
    """``text`` with every character a terminal would act on (newlines, NUL, ANSI escapes, bidi
    controls) shown as its Python escape: a value read from a file can never forge a second line."""
    text = str(text)
    return text if text.isprintable() else "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


class InputError(Exception):
    """Bad user input: a problem, sweep, fit or data file, or a command-line argument.

    Rendered by the command line as one line ``error: <file>: <key>: <reason>``
    and exit status 2; the parts keep the values as given, the line escapes them (:func:`printable`)."""

    def __init__(self, file, key, reason):
        self.file = str(file)
        self.key = str(key)
        self.reason = str(reason)
        super().__init__(str(self))

    def __str__(self):
        return f"{printable(self.file)}: {printable(self.key)}: {printable(self.reason)}"


class ArgumentError(ValueError):
    """Bad input to the Python API: ``argument`` names the argument, ``reason`` says what is wrong.

    The message is ``"<argument>: <reason>"``, the command line's ``<key>: <reason>``."""

    def __init__(self, argument: str, reason: str):
        self.argument = str(argument)
        self.reason = str(reason)
        super().__init__(f"{self.argument}: {self.reason}")
