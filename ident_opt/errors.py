"""The one exception type that means "the user's input is wrong" (exit status 2, no traceback), and the one way a
message shows a value (`excerpt`)."""

from typing import Any


class InputError(Exception):
    """Bad input or bad usage: a message that names the file, key, column or row at fault."""


def excerpt(value: Any, limit: int = 60) -> str:
    """A value as a message shows it: NumPy scalars and arrays as plain Python values (`inf`, not
    `np.float64(inf)`), as Python writes them (repr), cut to about `limit` characters (a huge list must not become
    a megabyte-long line)."""
    if type(value).__module__ == "numpy" and hasattr(value, "tolist"):  # NumPy itself is not imported for this
        value = value.tolist()
    text = repr(value)
    if len(text) <= limit:
        return text
    return text[: limit - 5] + " ...]" if isinstance(value, list) else text[:limit] + "..."
