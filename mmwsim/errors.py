"""The one exception type for user mistakes in :mod:`mmwsim`.

The CLI prints the message of a :class:`MmwsimError` as one line and exits
with status 2; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations


class MmwsimError(Exception):
    """A user mistake: bad file, key, value or argument.

    The message is one line that names the file, key or value at fault.
    """


class MaterialRangeWarning(UserWarning):
    """A material is used outside the frequency range its parameters are stated for."""
