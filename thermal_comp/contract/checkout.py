"""Where the project's git checkout is, for the commands that need more than the wheel carries.

The wheel ships the Python package. The firmware sources (``hil``, ``cnc``), the example runs
(the demo, ``cnc``, ``cnc.faults``) and the Makefile stay in the checkout. Those commands find
it beside the package (an editable or in-place install) or at ``$THERMAL_COMP_CHECKOUT``; from a
wheel without either they stop with what is missing and how to point at it, not a traceback.
"""

from __future__ import annotations

import os
from pathlib import Path

from thermal_comp.contract.errors import InputError

ENV = "THERMAL_COMP_CHECKOUT"
BESIDE = Path(__file__).resolve().parents[2]  # the checkout, when the package lies in one


class CheckoutMissing(InputError):
    """A command needs files of the git checkout that this installation does not have."""


def root() -> Path:
    """The checkout: ``$THERMAL_COMP_CHECKOUT`` if set, else the folder holding the package."""
    env = os.environ.get(ENV)
    return Path(env).expanduser().resolve() if env else BESIDE


def require(what: str, *parts: str) -> Path:
    """The checkout's root if it has every one of ``parts`` (paths inside it), else
    CheckoutMissing naming ``what`` needs them."""
    base = root()
    missing = [p for p in parts if not (base / p).exists()]
    if missing:
        raise CheckoutMissing(
            f"{what} needs the project's git checkout, and {base} has no {', '.join(missing)}. "
            f"The installed package carries the Python tools only: run it from a checkout, or "
            f"set {ENV} to one.")
    return base
