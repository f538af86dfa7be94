"""The project's own error base class: bad input, reported to the user with where and why.

Every domain error (a malformed run, a model.json that breaks the schema, a model codegen
refuses, ...) derives from ``InputError``; the `host` CLI turns exactly these into a message and
exit code 2, so a programming error still shows its traceback instead of a tidy lie.
``InputError`` is a ``ValueError`` so library callers can keep catching that.
"""

from __future__ import annotations


class InputError(ValueError):
    """Input the project cannot use; the message names the file, line, column, key or limit."""

    def __reduce__(self):
        # Picklable whatever a subclass's __init__ takes (RunFormatError: path, message, line,
        # column): an error raised in a worker process reaches the parent as itself, not as
        # "BrokenProcessPool" after the unpickling failed. Rebuilt from its message and fields.
        return (_restore, (type(self), self.args, dict(self.__dict__)))


def _restore(cls: type, args: tuple, state: dict) -> InputError:
    err = cls.__new__(cls)
    err.args = args
    err.__dict__.update(state)
    return err


class MissingColumnError(InputError, KeyError):
    """A column (sensor, target, aux input) the caller asked for is not in the data."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""
