"""Stage packages that are also their stage's verb.

``msleak.predict`` and ``msleak.leakage`` are packages (``msleak.predict.engine``, ...) and
the public verbs of the same names: importing a subpackage makes it the attribute of
``msleak``, so the package itself is made callable and calls the verb.
"""

from __future__ import annotations

import inspect
import sys
import types
from typing import Callable


def make_callable(package: str, verb: Callable) -> None:
    """Make the already-imported module ``package`` call ``verb`` when called; its help
    and signature are the verb's (``help(msleak.predict)``)."""
    module = sys.modules[package]

    class VerbPackage(types.ModuleType):
        __call__ = staticmethod(verb)

    VerbPackage.__doc__ = verb.__doc__
    module.__class__ = VerbPackage
    module.__signature__ = inspect.signature(verb)
