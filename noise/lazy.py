"""Lazy package exports: a name is imported from its module on first use.

``noise``, ``scenesim`` and ``scenesim.batch`` keep ``import`` cheap (the command
line imports only what a subcommand runs) by mapping each public name to the module
that defines it.
"""

import importlib

__all__ = ["lazy_exports"]


def lazy_exports(package, exports, namespace):
    """Module ``__getattr__`` and ``__dir__`` for ``package``'s lazy ``exports``
    (``{name: module}``); ``namespace`` is the package's ``globals()``, where each
    name is cached once imported."""

    def __getattr__(name):
        try:
            module = exports[name]
        except KeyError:
            raise AttributeError(
                f"module {package!r} has no attribute {name!r}") from None
        value = getattr(importlib.import_module(module), name)
        namespace[name] = value
        return value

    def __dir__():
        return sorted(set(namespace) | set(exports))

    return __getattr__, __dir__
