"""Stage packages that are also their stage's verb.

``msleak.predict`` and ``msleak.leakage`` are packages of numerics and the names of the
public verbs (:mod:`msleak.verbs`): importing a subpackage makes it the attribute of
``msleak``, so the package itself is made callable and calls the verb. The verb is named by
its dotted path and imported on the first call (or the first look at its help), so a
computation package never imports the verb layer above it.
"""

from __future__ import annotations

import importlib
import inspect
import sys
import types


def resolve(path: str):
    """The function named ``"module:function"``, imported."""
    module, _, name = path.partition(":")
    return getattr(importlib.import_module(module), name)


def make_callable(package: str, verb: str) -> None:
    """Make the already-imported module ``package`` call the function ``verb``
    ("module:function") when called; its help and signature are the verb's
    (``help(msleak.predict)``)."""
    module = sys.modules[package]
    own_doc = module.__doc__

    class VerbPackage(types.ModuleType):
        def __call__(self, *args, **kwargs):
            return resolve(verb)(*args, **kwargs)

        @property
        def __signature__(self):
            return inspect.signature(resolve(verb))

        @property
        def __wrapped__(self):
            return resolve(verb)

    VerbPackage.__doc__ = own_doc
    module.__class__ = VerbPackage
