"""The one exception type the commands turn into a one-line message."""


class BloomError(Exception):
    """Bad input: a missing file, a broken mesh, a wrong config key or value.

    The message names the file (and the key, where there is one) and says what to do;
    the command line prints it on one line and exits non-zero without writing output.
    """

    def __init__(self, message: str, *, where: str | None = None):
        self.where = where
        super().__init__(f"{where}: {message}" if where else message)
