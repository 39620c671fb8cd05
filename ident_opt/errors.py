"""The one exception type that means "the user's input is wrong" (exit status 2, no traceback)."""


class InputError(Exception):
    """Bad input or bad usage: a message that names the file, key, column or row at fault."""
