"""Every public function with four or more parameters documents them all, numpy style.

The public API is walked with :mod:`inspect`: every module of the package whose dotted
path has no private part, the functions and classes it defines (not those it imports)
whose names are public, and the public methods, ``__init__`` and ``__call__`` of those
classes. A callable with four or more parameters (``self`` and ``cls`` aside) needs a
``Parameters`` section that names each of its parameters (for a constructor: in the class
docstring or in ``__init__``'s; a method without a docstring of its own is judged by the
one it inherits, as the API reference shows it). The ``__init__`` a dataclass or named tuple
generates is left out: its fields are the documentation (``#:`` comments or an
``Attributes`` section, read by the API reference).

A ``Parameters`` section lists nothing but parameters (prose after the entries reads as
one more: the API reference's strict build fails on it).

The rule has no exceptions.
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import pkgutil
import re
from collections.abc import Callable, Iterator
from typing import Any

import conformal_control

MIN_PARAMETERS = 4

_SECTION = re.compile(r"^(?P<title>[A-Z][A-Za-z ]+)\n-{3,}[ \t]*$", re.M)
_ENTRY = re.compile(r"^(?P<names>\*{0,2}[A-Za-z_][\w]*(?:\s*,\s*\*{0,2}[A-Za-z_][\w]*)*)\s*(?::|$)")


def _public_modules() -> Iterator[str]:
    yield "conformal_control"
    for info in pkgutil.walk_packages(conformal_control.__path__, "conformal_control."):
        if not any(part.startswith("_") for part in info.name.split(".")[1:]):
            yield info.name


def _parameters(func: Callable[..., Any]) -> list[str]:
    try:
        signature = inspect.signature(func)
    except (TypeError, ValueError):  # builtins without a signature
        return []
    names = list(signature.parameters)
    in_class = "." in func.__qualname__.replace(".<locals>.", "")
    if in_class and names and names[0] in ("self", "cls"):
        names = names[1:]
    return names


def documented_parameters(doc: str) -> set[str] | None:
    """The names a numpy-style ``Parameters`` section lists (None: no such section)."""
    sections = list(_SECTION.finditer(doc))
    for i, match in enumerate(sections):
        if match.group("title").strip() != "Parameters":
            continue
        end = sections[i + 1].start() if i + 1 < len(sections) else len(doc)
        names: set[str] = set()
        for line in doc[match.end() : end].splitlines():
            if not line or line[0].isspace():
                continue  # blank, or the description of the entry above
            entry = _ENTRY.match(line)
            if entry:
                names.update(n.strip().lstrip("*") for n in entry.group("names").split(","))
        return names
    return None


def _callables() -> Iterator[tuple[str, Callable[..., Any], str]]:
    """(qualified name, callable, the docstring judged) of the public API."""
    for module_name in _public_modules():
        module = importlib.import_module(module_name)
        for attr, obj in sorted(vars(module).items()):
            if attr.startswith("_") or getattr(obj, "__module__", None) != module_name:
                continue
            if inspect.isfunction(obj):
                yield f"{module_name}.{attr}", obj, inspect.getdoc(obj) or ""
            elif inspect.isclass(obj):
                generated = dataclasses.is_dataclass(obj) or issubclass(obj, tuple)
                for name, member in vars(obj).items():
                    if name.startswith("_") and name not in ("__init__", "__call__"):
                        continue
                    if isinstance(member, (staticmethod, classmethod)):
                        member = member.__func__
                    if not inspect.isfunction(member):
                        continue
                    if name == "__init__":
                        if generated and member.__code__.co_filename.startswith("<"):
                            continue  # written by dataclasses / namedtuple
                        doc = "\n".join(  # their own docstrings, not inherited ones
                            inspect.cleandoc(d) for d in (obj.__doc__, member.__doc__) if d
                        )
                    else:
                        doc = inspect.getdoc(getattr(obj, name)) or ""
                    yield f"{module_name}.{attr}.{name}", member, doc


def _missing() -> dict[str, str]:
    """Callables with four or more parameters and what their docstring lacks."""
    out: dict[str, str] = {}
    for qualname, func, doc in _callables():
        params = _parameters(func)
        if len(params) < MIN_PARAMETERS:
            continue
        listed = documented_parameters(doc)
        if listed is None:
            out[qualname] = "no Parameters section"
        elif absent := [p for p in params if p not in listed]:
            out[qualname] = f"Parameters section without {', '.join(absent)}"
    return out


def _strangers() -> dict[str, list[str]]:
    """Callables whose ``Parameters`` section lists a name their signature lacks (the API
    reference's strict build fails on them; prose after the entries reads as one)."""
    out: dict[str, list[str]] = {}
    for qualname, func, doc in _callables():
        if func.__doc__ is None and not qualname.endswith("__init__"):
            continue  # judged by an inherited docstring: the base's parameters
        listed = documented_parameters(doc)
        params = set(_parameters(func))
        if listed and params and (extra := sorted(listed - params)):
            out[qualname] = extra
    return out


def test_the_section_parser_reads_numpy_entries() -> None:
    doc = inspect.cleandoc(
        """Summary.

        Parameters
        ----------
        a, b : float
            Two numbers.
        c
            Untyped.
        **kwargs
            The rest.

        Returns
        -------
        float
        """
    )
    assert documented_parameters(doc) == {"a", "b", "c", "kwargs"}
    assert documented_parameters("Summary only.") is None


def test_every_public_function_with_four_parameters_documents_them() -> None:
    missing = _missing()
    assert not missing, "document the parameters (numpy style) of:\n" + "\n".join(
        f"  {k}: {v}" for k, v in sorted(missing.items())
    )


def test_a_parameters_section_lists_only_parameters() -> None:
    strangers = _strangers()
    assert not strangers, "Parameters sections naming what is not a parameter:\n" + "\n".join(
        f"  {k}: {', '.join(v)}" for k, v in sorted(strangers.items())
    )
