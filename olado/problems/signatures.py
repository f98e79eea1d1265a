"""The check of a DOCP's user functions against the arguments olado passes
(:meth:`olado.problems.docp.DOCP.check_functions`), with what it accepted remembered: a solve
checks its problem at entry and a problem checks itself when it is built, and inspect.signature
costs tens of microseconds a function (a small problem's solve takes milliseconds).

Two memories, both weak (a class or function that goes away is forgotten):

* per Python function, the (method name, bound or not) keys whose signature was accepted;
* per DOCP class, the tuple of its functions (plain Python functions of the class, in the order
  of the call table) that passed the whole check: an instance that replaces none of them on
  itself is not checked again -- the class's functions are the same objects, so the check
  would find what it found before.
"""

from __future__ import annotations

import inspect
import types
import weakref

from ..errors import ProblemDefinitionError

#: the Python functions whose signature check_signatures accepted, per (method name, bound or not)
_SIGNATURES_CHECKED = weakref.WeakKeyDictionary()
#: per DOCP class, its functions (plain Python functions, in the call table's order) that passed
_CLASSES_CHECKED = weakref.WeakKeyDictionary()


def _signature_key(fn, name):
    """(plain function, key) for a Python function or method, else None (not remembered)."""
    if isinstance(fn, types.MethodType) and isinstance(fn.__func__, types.FunctionType):
        return fn.__func__, (name, True)
    if isinstance(fn, types.FunctionType):
        return fn, (name, False)
    return None


def _checked_before(fn, name):
    found = _signature_key(fn, name)
    return found is not None and found[1] in _SIGNATURES_CHECKED.get(found[0], ())


def _remember_checked(fn, name):
    found = _signature_key(fn, name)
    if found is not None:
        _SIGNATURES_CHECKED.setdefault(found[0], set()).add(found[1])


def check_signatures(problem, calls, describe):
    """Every function of ``calls`` (name -> argument names) on ``problem`` is callable with those
    arguments; ProblemDefinitionError naming the function otherwise (``describe``: how a value
    that is not callable is named in the message)."""
    cls = type(problem)
    funcs = tuple(getattr(cls, name, None) for name in calls)
    plain = (all(type(f) is types.FunctionType for f in funcs)
             and not any(name in calls for name in getattr(problem, "__dict__", calls)))
    if plain and _CLASSES_CHECKED.get(cls) == funcs:
        return
    for name, args in calls.items():
        fn = getattr(problem, name, None)
        call = f"{name}({', '.join(args)})"
        if not callable(fn):
            raise ProblemDefinitionError(f"must be a method called as {call}, got {describe(fn)}", function=name)
        if not problem._overrides(name) or _checked_before(fn, name):
            continue
        try:
            signature = inspect.signature(fn)
        except (TypeError, ValueError):  # a builtin or compiled function: no signature to check
            continue
        try:
            signature.bind(*args)
        except TypeError:
            raise ProblemDefinitionError(f"olado calls it as {call}, but its signature is "
                                         f"{name}{signature}", function=name) from None
        _remember_checked(fn, name)
    if plain:
        _CLASSES_CHECKED[cls] = funcs
