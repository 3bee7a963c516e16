"""Errors shared by every layer."""


class InputError(Exception):
    """Bad user input: a problem, sweep, fit or data file, or a command-line argument.

    Rendered by the command line as one line ``error: <file>: <key>: <reason>``
    and exit status 2.
    """

    def __init__(self, file, key, reason):
        self.file = str(file)
        self.key = str(key)
        self.reason = str(reason)
        super().__init__(f"{self.file}: {self.key}: {self.reason}")
